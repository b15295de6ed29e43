"""The reference decoder in-process (``adapters/reference-inprocess.toml``): :mod:`.refdecoder`'s chain."""
from __future__ import annotations

from pathlib import Path

from fbaconf.pipeline import multi_outputs, reference_outputs

from .adapters import Job, PythonAdapter
from .refdecoder import _is_text


class ReferenceAdapter(PythonAdapter):
    description = "fbaconf reference decoder, in-process"
    supports_multi = True

    def run(self, job: Job) -> None:
        if job.faces:
            multi_outputs([Path(f) for f in job.faces], job.path("faps_out_dir"), self.faps_format)
            return
        def want(out: str, ph: str):
            return job.path(ph) if out in self.outputs and ph not in job.unwanted else None
        reference_outputs(job.path("input"), scene=job.path("scene"), scenario=job.path("scenario"),
                          faps_out=want("faps", "faps_out"), vertices_out=want("vertices", "vertices_out"),
                          images_dir=want("images", "images_dir"), player_state=_is_text(job.path("input")))
