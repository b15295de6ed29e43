"""Running a decoder on derived inputs, exactly as a case is run: the variant is a case of its
own (the original's inputs, one of them edited) with goldens the reference makes from the
variant, run through the harness's runner, so a command decoder runs in the sandbox with the
manifest's limits and never sees the goldens. Every run is counted against a budget."""

from __future__ import annotations

import dataclasses
import shutil
import tempfile
from pathlib import Path
from types import TracebackType

from fbaconf.conformance.golden import generate_case
from fbaconf.conformance.suite import Case
from fbaconf.harness.adapters import Adapter
from fbaconf.harness.results import CaseResult
from fbaconf.harness.runner import RunContext, run_case


@dataclasses.dataclass(frozen=True)
class Budget:
    """How many extra decoder runs explain may make: per cause (each variant and, where the
    variant also normalises the text's form, its control), per case run again to see whether its
    outcome is reproducible, and the most causes it confirms. ``bound`` is the most runs in all."""

    per_cause: int = 6
    reruns: int = 4
    rerun_cases: int = 16
    max_causes: int = 12

    @property
    def bound(self) -> int:
        return self.per_cause * self.max_causes + self.reruns * self.rerun_cases


class Runner:
    """Runs variants and reruns of cases through ``adapter``; ``runs`` counts them."""

    def __init__(self, adapter: Adapter, claim: str | None, budget: Budget) -> None:
        self.adapter, self.claim, self.budget = adapter, claim, budget
        self.runs = 0
        self._tmp = Path(tempfile.mkdtemp(prefix="fbaconf-explain-"))
        self._n = 0

    def __enter__(self) -> Runner:
        return self

    def __exit__(self, t: type[BaseException] | None, e: BaseException | None, tb: TracebackType | None) -> None:
        shutil.rmtree(self._tmp, ignore_errors=True)

    @property
    def left(self) -> int:
        return self.budget.bound - self.runs

    def rerun(self, case: Case, golden: Path | None = None) -> CaseResult:
        """The case itself once more, against its committed goldens."""
        self.runs += 1
        ctx = self._ctx(golden) if golden is not None else self._ctx(None)
        return run_case(ctx, case)

    def variant(self, case: Case, key: str, data: bytes, label: str) -> tuple[CaseResult, Path]:
        """``case`` with its input ``key`` replaced by ``data``: its result, and where the variant's
        input was kept (for the reproduce line)."""
        self._n += 1
        vid = f"{case.id}~{label}"
        root = self._tmp / f"v{self._n}"
        sdir = root / "suites" / case.suite
        sdir.mkdir(parents=True)
        if case.suite_dir is None:
            raise ValueError(f"{case.full_id}: a case without its suite folder has no inputs to edit")
        for k, rel in case.inputs.items():
            if k != "faces" and isinstance(rel, str):
                src = case.suite_dir / rel
                if src.is_file():
                    (sdir / rel).parent.mkdir(parents=True, exist_ok=True)
                    shutil.copyfile(src, sdir / rel)
        for rel in case.sha256:
            src = case.suite_dir / rel
            if src.is_file() and not (sdir / rel).exists():
                (sdir / rel).parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(src, sdir / rel)
        target = sdir / case.inputs[key]
        target.write_bytes(data)
        # the variant is the one input edited: the other form of the stream (the fba's decoding as
        # text, or the stream a text was decoded from) is no longer the same content, so it goes
        other = "fap" if key == "fba" else "fba"
        if isinstance(case.inputs.get(other), str):
            (sdir / case.inputs[other]).unlink(missing_ok=True)
        var = dataclasses.replace(case, id=vid, suite_dir=sdir, sha256={})
        var.inputs = {k: v for k, v in case.inputs.items() if k != other}
        golden = root / "golden"
        generate_case(var, golden / case.suite / vid)
        self.runs += 1
        return run_case(self._ctx(golden), var), target

    def _ctx(self, golden: Path | None) -> RunContext:
        work = self._tmp / "work"
        work.mkdir(exist_ok=True)
        if golden is None:
            return RunContext(self.adapter, self.claim, self._tmp / "out", work_root=work)
        return RunContext(self.adapter, self.claim, self._tmp / "out", golden=golden, work_root=work)

    def keep(self, src: Path, dest_dir: Path) -> Path:
        """Copy a variant's input out of the scratch folder (it is removed at the end)."""
        dest_dir.mkdir(parents=True, exist_ok=True)
        out = dest_dir / src.name
        shutil.copyfile(src, out)
        return out
