"""Damaged ADC frame streams (``openemt bench fuzz``, section ``framing``).

Every case packs a stream of frames (random sample format, channel count, samples per frame,
start counter, some with the start flag) with :func:`openemt.live._framing.pack_frame`, damages
it at random (bits flipped, bytes cut, junk inserted, a frame duplicated, two frames swapped,
the stream cut short) and feeds it to a :class:`~openemt.live._framing.FrameDecoder` in pieces
of random sizes. It holds when the decoder raises nothing, every frame it accepts is one that
was sent, whole (counter, flags and samples), and every frame that was sent but not accepted
is accounted for by a CRC error, a bad header, skipped or still pending bytes. Findings:
``crash`` (an exception), ``garbage`` (an accepted frame that was not sent) and
``unaccounted`` (frames missing without a count).
"""

from __future__ import annotations

import random
import time

import numpy as np

__all__ = ["fuzz_framing"]


def _stream(rng: random.Random):
    from openemt.live._framing import FLAG_START, pack_frame

    fmt = rng.choice(["int16", "int32", "float32"])
    ch, n = rng.randint(1, 12), rng.randint(1, 96)
    fs = rng.choice([1000.0, 48000.0, 96000.0, 250000.0])
    counter = rng.randrange(0, 1 << 40)
    k = rng.randint(1, 20)
    nrng = np.random.default_rng(rng.randrange(1 << 30))
    frames, sent = [], {}
    for i in range(k):
        x = nrng.integers(-30000, 30000, size=(n, ch))
        flags = FLAG_START if (i == 0 or rng.random() < 0.05) else 0
        f = pack_frame(x, counter, fs, fmt=fmt, scale=0.25, flags=flags)
        frames.append(f)
        sent[(counter, flags)] = 0.25 * x          # integers: exact in every format
        counter += n
    return ch, fs, frames, sent


def _damage(rng: random.Random, frames: list) -> tuple:
    frames = list(frames)
    ops = []
    if len(frames) > 1 and rng.random() < 0.2:
        i = rng.randrange(len(frames) - 1)
        frames[i], frames[i + 1] = frames[i + 1], frames[i]
        ops.append(("swap", i))
    if rng.random() < 0.2:
        i = rng.randrange(len(frames))
        frames.insert(i, frames[i])
        ops.append(("duplicate", i))
    data = bytearray(b"".join(frames))
    for _ in range(rng.randint(0, 5)):
        what = rng.choice(["flip", "cut", "junk", "truncate"])
        if not data:
            break
        at = rng.randrange(len(data))
        if what == "flip":
            data[at] ^= 1 << rng.randrange(8)
        elif what == "cut":
            del data[at:at + rng.randint(1, 40)]
        elif what == "junk":
            data[at:at] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 40)))
        else:
            del data[at:]
        ops.append((what, at))
    return bytes(data), ops


def fuzz_framing(n_cases: int, seed: int = 0, progress=None) -> dict:
    from openemt.live._framing import FrameDecoder

    rng = random.Random(seed)
    out = {"cases": n_cases, "held": 0, "crash": 0, "garbage": 0, "unaccounted": 0,
           "frames_sent": 0, "frames_accepted": 0, "max_case_s": 0.0, "examples": []}
    for case in range(n_cases):
        t0 = time.perf_counter()
        ch, fs, frames, sent = _stream(rng)
        data, ops = _damage(rng, frames)
        d = FrameDecoder(ch, fs)
        got, kind = [], None
        try:
            i = 0
            while i < len(data):
                step = rng.randint(1, 4096)
                got += d.feed(data[i:i + step])
                i += step
        except Exception as exc:  # noqa: BLE001 - any exception is a finding
            kind, why = "crash", f"{type(exc).__name__}: {exc}"
        if kind is None:
            for counter, flags, x in got:
                want = sent.get((counter, flags))
                if want is None or want.shape != x.shape or not np.array_equal(want, x):
                    kind, why = "garbage", f"accepted frame {counter} was not sent"
                    break
        if kind is None and len({(c, f) for c, f, _ in got}) < len(frames):
            if not (d.crc_errors or d.bad_headers or d.bytes_skipped or d.pending
                    or any(op[0] == "truncate" for op in ops)):
                kind, why = "unaccounted", "frames missing without a count"
        out["frames_sent"] += len(frames)
        out["frames_accepted"] += len(got)
        out["max_case_s"] = max(out["max_case_s"], time.perf_counter() - t0)
        if kind is None:
            out["held"] += 1
        else:
            out[kind] += 1
            if len(out["examples"]) < 20:
                out["examples"].append({"case": case, "seed": seed, "kind": kind,
                                        "ops": ops, "message": why})
        if progress is not None:
            progress(1)
    out["findings"] = out["crash"] + out["garbage"] + out["unaccounted"]
    return out
