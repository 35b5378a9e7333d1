"""A pyigtl client polling some devices on its own thread, as a viewer such as 3D Slicer would,
keeping every new message: ``got[device]`` lists ``(timestamp, matrix)`` for TRANSFORMs and
``(timestamp, text)`` for STRING messages, or with ``whole=True`` every message object as it
arrived (metadata included). ``announce=True``: it sends a version-2 GET_STATUS first, as a
client that reads version-2 messages does (the server answers with STATUS, which pyigtl does
not decode, and sends version 2 from then on)."""

from __future__ import annotations

import threading

import numpy as np
import pyigtl


class Listener:
    def __init__(self, port, devices, whole=False, announce=False):
        self.client = pyigtl.OpenIGTLinkClient(host="127.0.0.1", port=port)
        # announced once connected: pyigtl drops what was queued before a failed connect (the
        # server may start after the viewer, as Slicer's connector waits for it)
        self._announce = announce
        self.devices = devices
        self.whole = whole
        self.got = {d: [] for d in devices}
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self):
        while not self._done.is_set():
            if self._announce and self.client.is_connected():
                from _igtl_decode import GetStatus

                self.client.send_message(GetStatus(2), wait=False)
                self._announce = False
            for d in self.devices:
                m = self.client.wait_for_message(d, timeout=0.005 if self.whole else 0.01)
                if m is not None and self.whole:
                    self.got[d].append(m)
                elif m is not None and (not self.got[d] or m.timestamp != self.got[d][-1][0]):
                    self.got[d].append((m.timestamp, np.array(getattr(m, "matrix", None))
                                        if hasattr(m, "matrix") else m.string))

    def stop(self):
        self._done.set()
        self._thread.join(timeout=3.0)
        self.client.stop()
