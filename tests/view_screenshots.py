"""Make the screenshots of docs/live.md#live-view: the simulated tracker (one sensor, a
conductive object near it) tracked with the live view open, one PNG per panel
(``?panel=NAME``), taken by headless Chromium (``Page.captureScreenshot``, what
``chromium --headless --screenshot`` does) once the page shows the end of the session;
``view-collect.png``: the collect panel at the end of a simulated collection (a robot
reference, 20 dwells).

    .venv/bin/python tests/view_screenshots.py docs/img [PANEL ...]
"""

from __future__ import annotations

import sys
import threading
import time
from pathlib import Path

from _cdp import SOURCE_JS, Browser

from openemt.live import TrackingSession, TrackOptions
from openemt.view import LiveFeed, ViewServer
from openemt.view._page import COLLECT_PANELS, PANELS

SIZES = {"carriers": (760, 170), "spectrum": (930, 372), "coupling": (620, 160),
         "sensors": (1080, 110), "trail": (960, 390), "collect": (1250, 440)}


def collect_shot(out: Path) -> None:
    from openemt.collect import CollectOptions, collect

    feed = LiveFeed()
    feed.source = "collect --source sim --simulate-reference robot"
    opts = CollectOptions(output=out / "collect-screenshot.h5", simulate_reference="robot",
                          n_poses=20, sim_speed=10)
    with ViewServer(feed, panels=COLLECT_PANELS) as server, Browser() as browser:
        try:
            r = collect(opts, observer=feed)
        finally:
            (out / "collect-screenshot.h5").unlink(missing_ok=True)
        browser.open(f"{server.url}?panel=collect")
        browser.wait_for(f"(() => {{ const d = {SOURCE_JS.format(name='collect')}; "
                         f"return d && d.state && d.state[0].startsWith('ended'); }})()")
        time.sleep(1.0)                         # drawn
        w, h = SIZES["collect"]
        browser.screenshot(out / "view-collect.png",
                           clip={"x": 0, "y": 0, "width": w, "height": h})
        print(f"{out / 'view-collect.png'} ({r.n_poses} dwells)", file=sys.stderr)


def main(folder: str, panels=()) -> None:
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    if not panels or "collect" in panels:
        collect_shot(out)
    panels = [p for p in PANELS if not panels or p in panels]
    if not panels:
        return
    feed = LiveFeed()
    opts = TrackOptions(duration=3.0, igtl=False, quiet=True, eddy=0.02)
    with ViewServer(feed) as server, Browser() as browser:
        def track():
            with TrackingSession.from_tracker(None, opts, observer=feed) as session:
                session.run()

        run = threading.Thread(target=track)
        run.start()
        run.join()
        n = feed.n_samples[0]
        for panel in panels:
            browser.open(f"{server.url}?panel={panel}")
            browser.wait_for(f"(() => {{ const d = {SOURCE_JS.format(name='header')}; "
                             f"return d && d.n_updates[0] > 0; }})()")
            time.sleep(1.0)                     # drawn
            w, h = SIZES[panel]
            browser.screenshot(out / f"view-{panel}.png",
                               clip={"x": 0, "y": 0, "width": w, "height": h})
            print(f"{out / f'view-{panel}.png'} ({n} samples)", file=sys.stderr)


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "docs/img", sys.argv[2:])
