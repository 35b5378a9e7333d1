"""Make the screenshots of docs/live.md#live-view: the simulated tracker (one sensor, a
conductive object near it) tracked with the live view open, one PNG per panel
(``?panel=NAME``), taken by headless Chromium (``Page.captureScreenshot``, what
``chromium --headless --screenshot`` does) once the page shows the end of the session.

    .venv/bin/python tests/view_screenshots.py docs/img
"""

from __future__ import annotations

import sys
import threading
import time
from pathlib import Path

from _cdp import SOURCE_JS, Browser

from openemt.live import TrackingSession, TrackOptions
from openemt.view import LiveFeed, ViewServer
from openemt.view._page import PANELS

SIZES = {"carriers": (760, 170), "spectrum": (930, 372), "coupling": (620, 310),
         "sensors": (1080, 110), "trail": (960, 390)}


def main(folder: str) -> None:
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
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
        for panel in PANELS:
            browser.open(f"{server.url}?panel={panel}")
            browser.wait_for(f"(() => {{ const d = {SOURCE_JS.format(name='header')}; "
                             f"return d && d.n_updates[0] > 0; }})()")
            time.sleep(1.0)                     # drawn
            w, h = SIZES[panel]
            browser.screenshot(out / f"view-{panel}.png",
                               clip={"x": 0, "y": 0, "width": w, "height": h})
            print(f"{out / f'view-{panel}.png'} ({n} samples)", file=sys.stderr)


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "docs/img")
