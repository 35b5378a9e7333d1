"""A tracking backend over raw samples held in memory, for the realtime-factor benchmarks."""

__all__ = ["Memory"]


class Memory:
    """Backend over raw samples held in memory (the realtime factor excludes simulation),
    repeated up to ``n`` samples (default: once)."""

    realtime = False        # read as fast as possible: no end-to-end latency

    def __init__(self, samples, layout, chunk, n=None):
        self.samples, self.layout, self.chunk = samples, layout, int(chunk)
        self.n = len(samples) if n is None else int(n)
        self.t0_epoch = 0.0
        self._i = 0

    def read(self):
        i = self._i
        if i >= self.n:
            return None
        k = i % len(self.samples)
        m = min(self.chunk, len(self.samples) - k, self.n - i)
        self._i = i + m
        return self.samples[k:k + m]

    def truth_poses(self, times):
        return None

    def close(self):
        pass
