"""What a timing was measured on: the machine (CPU model, cores, memory) and its load, so that every
figure a benchmark prints says how busy the machine was (a figure measured beside other work is not
a quiet machine's). Imported by the benchmark scripts; ``python benchmarks/machine.py`` prints it.
"""

from __future__ import annotations

import os
import platform
import resource
import time
from pathlib import Path


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def memory_gb() -> float | None:
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal:"):
                return int(line.split()[1]) / 1024**2
    except OSError:
        pass
    return None


def cores() -> int:
    """The cores this process may run on (a container's or taskset's share, not the host's)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


def load() -> float:
    """The 1-minute load average: runnable processes, this one included."""
    return os.getloadavg()[0]


def describe() -> str:
    mem = memory_gb()
    return (
        f"{cpu_model()}, {cores()} cores usable, {mem:.0f} GB" if mem else f"{cpu_model()}, {cores()} cores usable"
    ) + f"; load average {load():.2f} (1 min)"


class Clock:
    """Wall and CPU time of a block (this process and the children it waited for), and the load
    average before and after: ``with Clock() as c: ...; print(c.line())``."""

    def __enter__(self) -> Clock:
        self.load0 = load()
        self.wall0 = time.perf_counter()
        self.cpu0 = self._cpu()
        return self

    def __exit__(self, *exc) -> None:
        self.wall = time.perf_counter() - self.wall0
        self.cpu = self._cpu() - self.cpu0
        self.load1 = load()

    @staticmethod
    def _cpu() -> float:
        me = resource.getrusage(resource.RUSAGE_SELF)
        kids = resource.getrusage(resource.RUSAGE_CHILDREN)
        return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime

    def quiet(self) -> bool:
        """Was the machine quiet: a load average below one per core beyond this work's own."""
        return max(self.load0, self.load1) < 1.5

    def line(self) -> str:
        state = (
            "quiet"
            if self.quiet()
            else "busy (other work on the machine: wall times are longer than a quiet machine's)"
        )
        return (
            f"{self.wall:.1f} s wall, {self.cpu:.1f} s CPU; load average {self.load0:.2f} before, {self.load1:.2f} after: "
            f"{state}"
        )


if __name__ == "__main__":
    print(f"{platform.node()}: {describe()}")
