"""In-process HAL: direct calls into the emulator's Bench (CPython), no packets, for speed."""


class BenchHal:
    """``read_q1`` from ``bench.q1_sample()``, ``spi_write`` into ``bench.spi_write(word)``; packets to ``sent``."""

    def __init__(self, bench):
        self.bench = bench
        self.sent = []

    def read_q1(self, out):
        out[0], out[1], out[2] = self.bench.q1_sample()

    def spi_write(self, words, n):
        for k in range(n):
            self.bench.spi_write(words[k])

    def send(self, pid, dst, payload):
        self.sent.append((pid, dst, payload))

    def recv(self):
        return []
