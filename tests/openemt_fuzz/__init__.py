"""``openemt bench fuzz``: the long fuzz run of every reader, the CLI and every solver.

Reader and CLI cases are mutated files (:mod:`openemt_fuzz._fuzzcases`) run in a child process
that is killed and counted as a hang when it does not answer within the time limit; solver
samples are generated coupling matrices checked against an independent reference
(:mod:`openemt_fuzz._fuzzsolve`). The JSON counts every outcome; ``findings`` is the number of
crashes, hangs, vague errors, silent garbage and wrongly ``converged`` poses together (0 is the
target), with up to 20 reproducible examples (target, mutation list, message).
"""

from __future__ import annotations

import random
import tempfile
import time

from openemt._errors import InputError

__all__ = ["add_arguments", "run"]

_BAD = ("vague", "garbage", "crash", "hang")


def add_arguments(parser) -> None:
    parser.add_argument("--reader-cases", type=int, default=10000,
                        help="mutated files read by the readers, over all formats (10000)")
    parser.add_argument("--cli-cases", type=int, default=2000,
                        help="mutated files given to the CLI commands (2000)")
    parser.add_argument("--solver-samples", type=int, default=100000,
                        help="generated coupling matrices per solver (100000)")
    parser.add_argument("--live-cases", type=int, default=15,
                        help="hostile live-session cases: signals during a logged track "
                             "session, stalled sources (15)")
    parser.add_argument("--writer-rounds", type=int, default=1,
                        help="rounds of hostile output paths for every writing command "
                             "(openemt_fuzz._fuzzhostile_writers; 0 skips them) (1)")
    parser.add_argument("--navigate-cases", type=int, default=500,
                        help="generated navigation inputs given to pivot, spin, register, "
                             "assess and points (openemt_fuzz._fuzznavigate) (500)")
    parser.add_argument("--correct-cases", type=int, default=400,
                        help="generated correction cases: far poses, degenerate and oversized "
                             "correction files, apply workflow (openemt_fuzz._fuzzcorrect) "
                             "(400)")
    parser.add_argument("--reference-cases", type=int, nargs=3, default=(100, 100, 31),
                        metavar=("CLIENT", "CSV", "COLLECT"),
                        help="hostile references (openemt_fuzz._fuzzreference): servers read "
                             "by the reference client, reference CSVs, and collections against "
                             "either (100 100 31)")
    parser.add_argument("--metal-cases", type=int, default=300,
                        help="generated metal scenes, refused in one line or evaluated to "
                             "finite couplings (openemt_fuzz._fuzzmetal) (300)")
    parser.add_argument("--framing-cases", type=int, default=300,
                        help="damaged ADC frame streams fed to the frame decoder "
                             "(openemt_fuzz._fuzzframing) (300)")
    parser.add_argument("--bands-cases", type=int, default=300,
                        help="generated carrier-band inputs for the solver's band stage "
                             "(openemt_fuzz._fuzzbands) (300)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--time-limit", type=float, default=30.0,
                        help="seconds one case may take before it counts as a hang (30)")
    parser.add_argument("--hostile-cases", type=int, default=None,
                        help="runs of hostile reader inputs (links, external storage, "
                             "declared-shape bombs, FIFO/device paths, hostile tracker files), "
                             "spread over the list (default: all)")


def _files(args, kind: str, n: int, out: dict, examples: list, progress) -> None:
    from ._fuzzcases import (
        BYTE_OPS,
        CLI_COMMANDS,
        JSON_OPS,
        TARGETS,
        CaseRunner,
        case_bytes,
        prepare_targets,
        random_ops,
    )

    rng = random.Random(args.seed)
    names = [t for t in TARGETS if kind == "reader" or CLI_COMMANDS.get(t)]
    with tempfile.TemporaryDirectory(prefix="openemt-fuzz-") as tmp:
        targets = prepare_targets(f"{tmp}/seed")
        with CaseRunner(f"{tmp}/runner", time_limit=args.time_limit) as runner:
            for k in range(n):
                name = names[k % len(names)]
                target = targets[name]
                ops = random_ops(rng, BYTE_OPS, 4) if not target.json or rng.random() < 0.5 \
                    else []
                jops = random_ops(rng, JSON_OPS, 3) if target.json else []
                outcome = runner.run(name, case_bytes(target, ops, jops), cli=kind == "cli")
                counts = out.setdefault(name, {})
                counts[outcome.kind] = counts.get(outcome.kind, 0) + 1
                if outcome.kind in _BAD and len(examples) < 20:
                    examples.append({"kind": kind, "target": name, "outcome": outcome.kind,
                                     "ops": ops, "json_ops": jops,
                                     "message": outcome.message[:200]})
                progress(1)


def run(args) -> dict:
    for name in ("reader_cases", "cli_cases", "solver_samples", "live_cases", "writer_rounds",
                 "hostile_cases", "navigate_cases", "correct_cases"):
        if (getattr(args, name) or 0) < 0:
            raise InputError(f"expected --{name.replace('_', '-')} >= 0, "
                             f"got {getattr(args, name)}")
    if not args.time_limit > 0:
        raise InputError(f"expected --time-limit > 0 s, got {args.time_limit}")
    from openemt.cli._common import progress

    from ._fuzzsolve import fuzz_solvers

    t0 = time.perf_counter()
    examples: list = []
    readers: dict = {}
    cli: dict = {}
    total = args.reader_cases + args.cli_cases
    with progress(total=total, desc="fuzz files", args=args, unit="case") as bar:
        _files(args, "reader", args.reader_cases, readers, examples, bar.update)
        _files(args, "cli", args.cli_cases, cli, examples, bar.update)
    t_files = time.perf_counter() - t0
    solvers = fuzz_solvers(args.solver_samples, args.seed) if args.solver_samples else {}
    from ._fuzzhostile_live import fuzz_live

    with progress(total=args.live_cases, desc="hostile live", args=args, unit="case") as bar:
        hostile_live = fuzz_live(args.live_cases, args.seed, time_limit=max(args.time_limit, 30),
                                 progress=bar.update)
    writers = {}
    if args.writer_rounds:
        from ._fuzzhostile_writers import hostile_writers
        writers = hostile_writers(args.writer_rounds, time_limit=max(args.time_limit, 60.0))
    from ._fuzznavigate import fuzz_navigate

    with progress(total=args.navigate_cases, desc="navigation", args=args, unit="case") as bar:
        navigate = fuzz_navigate(args.navigate_cases, args.seed, time_limit=args.time_limit,
                                 progress=bar.update)
    from ._fuzzhostile_readers import n_runs, run_hostile_readers

    limit = args.hostile_cases
    with progress(total=n_runs(limit), desc="hostile readers", args=args, unit="run") as bar:
        hostile = run_hostile_readers(limit=limit, time_limit=args.time_limit,
                                      progress=bar.update)

    from ._fuzzcorrect import fuzz_corrections

    n_corr = getattr(args, "correct_cases", 0) or 0
    with progress(total=n_corr, desc="corrections", args=args, unit="case") as bar:
        corrections = fuzz_corrections(n_corr, args.seed, time_limit=args.time_limit,
                                       progress=bar.update)
    from ._fuzzreference import fuzz_reference

    n_ref = tuple(args.reference_cases)
    with progress(total=sum(n_ref), desc="hostile references", args=args, unit="case") as bar:
        reference = fuzz_reference(*n_ref, seed=args.seed, time_limit=max(args.time_limit, 90),
                                   progress=bar.update)

    from ._fuzzmetal import fuzz_metal

    n_metal = getattr(args, "metal_cases", 0) or 0
    with progress(total=n_metal, desc="metal scenes", args=args, unit="case") as bar:
        metal = fuzz_metal(n_metal, args.seed, time_limit=args.time_limit, progress=bar.update)

    from ._fuzzframing import fuzz_framing

    n_frm = max(0, getattr(args, "framing_cases", 0) or 0)
    with progress(total=n_frm, desc="ADC framing", args=args, unit="case") as bar:
        framing = fuzz_framing(n_frm, args.seed, progress=bar.update)

    from ._fuzzbands import fuzz_bands

    n_bands = max(0, getattr(args, "bands_cases", 0) or 0)
    with progress(total=n_bands, desc="carrier bands", args=args, unit="case") as bar:
        bands = fuzz_bands(n_bands, args.seed, time_limit=args.time_limit, progress=bar.update)

    def bad(counts):
        return {k: sum(c.get(k, 0) for c in counts.values()) for k in _BAD}

    files_bad = {k: bad(readers)[k] + bad(cli)[k] for k in _BAD}
    findings = sum(files_bad.values()) + solvers.get("wrong_converged", 0) \
        + solvers.get("crashes", 0) + hostile_live["findings"] + writers.get("broken", 0) \
        + hostile.get("findings", 0) + navigate["findings"] + corrections["findings"] \
        + reference["findings"] + metal["findings"]
    findings += framing["findings"]
    findings += bands["findings"]
    return {
        "reader_cases": args.reader_cases,
        "cli_cases": args.cli_cases,
        "solver_samples": solvers.get("n_samples", 0),
        "crashes": files_bad["crash"] + solvers.get("crashes", 0),
        "hangs": files_bad["hang"],
        "vague_errors": files_bad["vague"],
        "silent_garbage": files_bad["garbage"],
        "wrong_converged": solvers.get("wrong_converged", 0),
        "findings": findings,
        "readers": readers,
        "cli": cli,
        "solvers": solvers.get("by_solver", {}),
        "hostile_live": hostile_live,
        "hostile_writers": writers,
        "hostile_readers": hostile,
        "navigate": navigate,
        "corrections": corrections,
        "hostile_references": reference,
        "metal": metal,
        "framing": framing,
        "bands": bands,
        "examples": examples + solvers.get("examples", []),
        "seconds_files": round(t_files, 1),
        "seconds_total": round(time.perf_counter() - t0, 1),
    }
