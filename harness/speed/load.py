"""Whether a speed reading is the decoder's or the machine's: the CPU the decoder used, the
time it waited for a CPU, and what other processes took meanwhile (:mod:`.speed`).

Each timed run is a :class:`Window` between two :func:`~.sysinfo.machine_sample` readings:

- **the decoder's CPU time**: the rusage of its process tree (a spawned decoder, reaped by the
  harness), the ``schedstat`` of the live tree (a ``serve`` process), or of the calling thread
  (an in-process decoder);
- **the time it waited for a CPU**: the run-queue wait of its own threads (``schedstat``: a
  ``serve`` tree, an in-process decoder) — or, for a spawned decoder, whose threads are gone
  when the harness could read them, the machine's pressure stall time (PSI "some"), an upper
  bound (the time *any* task waited), else every moment it was not on a CPU;
- **what others took**: the machine's busy CPU time (``/proc/stat``) less this process's and
  its children's (the decoder's included) and a live ``serve`` tree's — during the runs, and
  between them, when no process of the decoder runs (so a decoder cannot pass its own
  busy-looping off as the machine's load: whatever it starts is its own CPU time, and it is
  dead between runs).

A run's *uncontended* time is its time less the wait other processes can explain: at most
what they took of every CPU (others' CPU seconds / CPUs), and at most the wait measured. The
verdict (:func:`verdict`): a rate that meets the minimum passes, whatever the load; one that
misses it is **inconclusive** only when the machine was busy with other work — others held at
least :data:`BUSY_SHARE` of the CPUs both during the runs and between them — and the
uncontended rate meets the minimum; otherwise it fails. A decoder that is slow by itself (it
sleeps, or waits on its own threads) on an idle machine fails: nothing excuses it.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..sysinfo import MachineSample

BUSY_SHARE = 0.10  # others used at least this share of the machine's CPUs: it was not the decoder's


@dataclass
class Window:
    """One timed run: its frames and time, the samples around it, the decoder's CPU and wait."""

    frames: int
    seconds: float  # the run's time, as the fit uses it
    before: MachineSample
    after: MachineSample
    cpu_s: float | None  # the decoder's CPU time during the run (None: unknown)
    stall_s: float | None  # the time it (or, "machine PSI", any task) waited for a CPU (None: unknown)
    stall_source: str  # "thread", "process tree", "machine PSI", "none"
    outside_own_s: float = 0.0  # the decoder's CPU time not in this process's rusage (a live serve tree)
    tree_before: float | None = None  # a live serve tree's CPU time at ``before`` / ``after`` (gaps)
    tree_after: float | None = None

    @property
    def span_s(self) -> float:
        return max(self.after.t - self.before.t, 1e-9)

    @property
    def others_s(self) -> float | None:
        """CPU seconds other processes used during the run."""
        return _others(self.before, self.after, self.outside_own_s)

    def uncontended_s(self, cpus: int) -> float:
        """The run's time without the wait other processes explain (module doc)."""
        others = self.others_s
        if others is None or not self.seconds > 0:
            return self.seconds
        waited = self.stall_s if self.stall_s is not None else self.seconds - (self.cpu_s or 0.0)
        credit = min(max(waited, 0.0), others / cpus, self.seconds)
        floor = (self.cpu_s or 0.0) / cpus  # never faster than its CPU time spread over every CPU
        return max(self.seconds - credit, min(floor, self.seconds))


def _others(a: MachineSample, b: MachineSample, outside_own_s: float = 0.0) -> float | None:
    if a.busy_s is None or b.busy_s is None:
        return None
    return max(0.0, (b.busy_s - a.busy_s) - (b.own_s - a.own_s) - outside_own_s)


@dataclass
class Load:
    """The machine during a measurement (every figure over the timed runs unless said)."""

    cpus: int
    wall_s: float  # the runs' time
    cpu_s: float | None  # the decoder's CPU time (None: not known for every run)
    stall_s: float | None  # the wait measured
    stall_source: str
    others_share: float | None  # share of the CPUs others used during the runs
    others_share_between: float | None  # ... between the runs
    load: float | None  # the highest 1-minute load average seen

    @property
    def busy(self) -> bool:
        """Whether other work held the machine, during and between the runs (module doc)."""
        return (
            self.cpu_s is not None
            and self.others_share is not None
            and self.others_share >= BUSY_SHARE
            and self.others_share_between is not None
            and self.others_share_between >= BUSY_SHARE
        )

    def describe(self) -> str:
        def pct(x: float | None) -> str:
            return "unknown" if x is None else f"{100 * x:.0f} %"

        cpu = "unknown" if self.cpu_s is None else f"{self.cpu_s:.2f} s"
        stall = "unknown" if self.stall_s is None else f"{self.stall_s:.2f} s ({self.stall_source})"
        load = "unknown" if self.load is None else f"{self.load:.1f}"
        return (
            f"runs {self.wall_s:.2f} s, decoder CPU {cpu}, waiting for a CPU {stall}; other processes used "
            f"{pct(self.others_share)} of the {self.cpus} CPUs during the runs and "
            f"{pct(self.others_share_between)} between them; load average {load}"
        )


def account(windows: list[Window], cpus: int) -> Load:
    """The :class:`Load` of a measurement's timed runs (in the order they ran)."""
    wall = sum(w.seconds for w in windows)
    cpus_s = [w.cpu_s for w in windows]
    cpu = None if any(c is None for c in cpus_s) else sum(c for c in cpus_s if c is not None)
    stalls = [w.stall_s for w in windows]
    stall = None if any(s is None for s in stalls) else sum(s for s in stalls if s is not None)
    sources = sorted({w.stall_source for w in windows})
    others = [w.others_s for w in windows]
    span = sum(w.span_s for w in windows)
    during = (
        None
        if not windows or any(o is None for o in others)
        else sum(o for o in others if o is not None) / (cpus * span)
    )
    gap_others, gap_span = 0.0, 0.0
    for a, b in zip(windows, windows[1:]):
        tree = (b.tree_before - a.tree_after) if a.tree_after is not None and b.tree_before is not None else 0.0
        o = _others(a.after, b.before, max(0.0, tree))
        if o is None:
            gap_span = 0.0
            break
        gap_others += o
        gap_span += max(b.before.t - a.after.t, 0.0)
    between = gap_others / (cpus * gap_span) if gap_span > 0 else None
    loads = [x.load for w in windows for x in (w.before, w.after) if x.load is not None]
    return Load(
        cpus=cpus,
        wall_s=wall,
        cpu_s=cpu,
        stall_s=stall,
        stall_source=", ".join(sources) or "none",
        others_share=during,
        others_share_between=between,
        load=max(loads) if loads else None,
    )


def verdict(rate: float, required: float, uncontended_rate: float | None, load: Load) -> tuple[str, str]:
    """("pass" | "fail" | "inconclusive", the reason in words) of a measured ``rate`` against
    ``required`` (module doc)."""
    if rate >= required:
        return "pass", f"{rate:.1f} fps meets the minimum {required:g} fps ({load.describe()})"
    if load.busy and uncontended_rate is not None and uncontended_rate >= required:
        return "inconclusive", (
            f"the machine was busy: {rate:.1f} fps measured is below the minimum {required:g} fps, but without "
            f"the wait other processes explain the rate is {uncontended_rate:.1f} fps — not the decoder's own "
            f"reading ({load.describe()}); measure again on a machine that is not busy"
        )
    if load.busy:
        why = (
            f"even without the wait other processes explain it is {uncontended_rate:.1f} fps"
            if uncontended_rate is not None
            else "what it waited for cannot be told"
        )
    else:
        why = "the machine was not busy with other work: the time is the decoder's own"
    return "fail", f"{rate:.1f} fps is below the minimum {required:g} fps; {why} ({load.describe()})"
