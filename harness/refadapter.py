"""The reference decoder in-process (``adapters/reference-inprocess.toml``): the chain
:mod:`fbaconf.reference.decoder` runs as a program."""

from __future__ import annotations

from pathlib import Path

from fbaconf.reference.pipeline import is_fap_text, multi_outputs, reference_outputs

from .adapters import Job, PythonAdapter


class ReferenceAdapter(PythonAdapter):
    description = "fbaconf reference decoder, in-process"
    supports_multi = True

    def run(self, job: Job) -> None:
        if job.faces:
            multi_outputs([Path(f) for f in job.faces], job.need("faps_out_dir"), self.faps_format)
            return

        def want(out: str, ph: str) -> Path | None:
            return job.path(ph) if out in self.outputs and ph not in job.unwanted else None

        reference_outputs(
            job.need("input"),
            scene=job.path("scene"),
            scenario=job.path("scenario"),
            faps_out=want("faps", "faps_out"),
            vertices_out=want("vertices", "vertices_out"),
            images_dir=want("images", "images_dir"),
            player_state=is_fap_text(job.path("input")),
        )
