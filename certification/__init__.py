"""Certification: run exactly what a claim requires and seal the result into a package a stranger
can check (``fbaconf certify``, ``certify verify``, ``certify keygen``).

* :mod:`.certify` — the ``certify`` run: the lab's isolation checks, the signing key read
  first, the cases the claim requires (through :mod:`fbaconf.harness.session`), the statement
  and the certificate;
* :mod:`.package` — sealing (``SHA256SUMS`` over every file, an Ed25519 ``SIGNATURE`` over
  the digest list) and verifying (every file read once, the verdict re-derived from
  ``results.jsonl`` and the claim rules);
* :mod:`.cli` — the ``certify`` verb.

This stage sits above :mod:`fbaconf.harness`, which runs the cases; the harness never imports it.
"""
