"""The ``fbaconf certify`` verb: certify a decoder (``--decoder D --claim P@L -o DIR [--key K]``),
verify a package (``certify verify DIR [--pubkey P]``), make a key pair (``certify keygen -o DIR``).

Exit codes of ``certify``: as ``fbaconf run`` (0 pass, 1 fail, 2 set-up error, 3 only speed
missed, 4 speed inconclusive: missed on a busy machine). ``certify verify``: 0 when every digest
and the verdict hold and the signature was checked (``--pubkey``), or the package is unsigned (its
line says so), or ``--unsigned-ok`` accepts a signature left unchecked — and the package's suites
and goldens are the ones this fbaconf ships (or ``--unofficial-ok``; the line says UNOFFICIAL
SUITES); 1 otherwise. A certificate made ``--allow-unisolated`` verifies with UNISOLATED in its line.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from fbaconf.harness.cli import lab_options
from fbaconf.harness.reports import clean_text
from fbaconf.harness.usage import UsageError
from fbaconf.isolation.bounds import ceilings_from

from . import certify
from .package import Signature, verify


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    c = sub.add_parser(
        "certify",
        help="certify a decoder for a claim (or verify a certificate, make a key)",
        description="`fbaconf certify --decoder D --claim P@L -o DIR [--key K]` runs exactly the "
        "cases the claim requires plus the speed measurement and writes a certification "
        "package (sha256 digests of every file, signed with an Ed25519 key when --key is "
        "given). `fbaconf certify verify DIR [--pubkey P]` re-checks a package. "
        "`fbaconf certify keygen -o DIR` makes a key pair.",
    )
    c.add_argument("action", nargs="?", choices=("verify", "keygen"), help="verify a package / make a key pair")
    c.add_argument("package", nargs="?", type=Path, help="(verify) the package folder")
    c.add_argument("--key", type=Path, help="sign the package with this Ed25519 private key (PEM)")
    c.add_argument("--pubkey", type=Path, help="(verify) check the package's signature with this public key")
    c.add_argument(
        "--unofficial-ok",
        action="store_true",
        help="(verify) accept a package whose suites or goldens are not the ones this fbaconf ships "
        "(exit 0, its line says UNOFFICIAL SUITES)",
    )
    c.add_argument(
        "--unsigned-ok",
        action="store_true",
        help="(verify) accept a signed package without checking its signature (no --pubkey): exit 0 "
        "when digests and verdict hold",
    )
    c.add_argument("--force", action="store_true", help="replace an existing certification package in -o")
    c.add_argument(
        "--allow-unisolated",
        action="store_true",
        help='certify even without bubblewrap or writable cgroups (the statement says "not isolated: '
        '…", naming what is missing)',
    )
    c.add_argument("--decoder", help="decoder manifest .toml or bundled adapter name")
    c.add_argument("--claim", help="profile@level to certify (default: the decoder's highest claim)")
    c.add_argument("-o", "--output", type=Path, help="package folder to write")
    c.add_argument("-j", "--jobs", type=int, default=None, help="parallel cases (default: CPU cores)")
    c.add_argument(
        "--cluster",
        metavar="local[:N]|tcp://HOST:PORT",
        help="run the cases as tasks on a Dask cluster instead of the local pool",
    )
    c.add_argument("--no-speed", action="store_true", help="skip the speed measurement (certificate says so)")
    lab_options(c)
    c.set_defaults(func=cmd_certify)


def cmd_certify(args: argparse.Namespace) -> int:
    if args.action == "keygen":
        if not args.output:
            raise UsageError("certify keygen needs -o DIR")
        key, pub = certify.keygen(args.output)
        print(f"wrote {key} (private: keep it secret) and {pub} (public: give it to whoever verifies)")
        return 0
    if args.action == "verify":
        if args.package is None:
            raise UsageError("certify verify: give the package folder")
        return _verify(args)
    if not args.decoder or not args.output:
        raise UsageError("--decoder and -o/--output are required")
    options = certify.CertifyOptions(
        jobs=args.jobs,
        speed=not args.no_speed,
        key=args.key,
        force=args.force,
        allow_unisolated=args.allow_unisolated,
        cluster=args.cluster,
        strict=args.strict,
        sandbox_ro=args.sandbox_ro,
        ceilings=ceilings_from(args),
    )
    return certify.certify(args.decoder, args.claim, args.output.resolve(), options)


def _verify(args: argparse.Namespace) -> int:
    """``certify verify``: one line on stdout (problems before it on stderr); exit 0 only when
    the digests and the verdict hold and the signature was checked — or the package is
    unsigned (the line says anyone could have written it), or --unsigned-ok."""
    v = verify(args.package, args.pubkey)
    for p in v.problems:
        print(f"certify verify: {clean_text(p)}", file=sys.stderr)
    what = " ".join(clean_text(str(v.certificate.get(k, "?")))[:80] for k in ("decoder", "claim"))
    verdict = clean_text(str(v.certificate.get("verdict", "?")))[:80]
    if not v.isolated:
        verdict += " — UNISOLATED (the decoder ran without the sandbox or cgroups: --allow-unisolated)"
    for u in v.unofficial:
        print(f"certify verify: {clean_text(u)}", file=sys.stderr)
    if v.unofficial:
        verdict += " — UNOFFICIAL SUITES (not the suites and goldens of the fbaconf that verifies)"
    if v.problems:
        print(f"certify verify: FAILED ({len(v.problems)} problem(s); {v.state})")
        return 1
    if v.unofficial and not args.unofficial_ok:
        print(
            f"certify verify: NOT VERIFIED (made with suites or goldens this fbaconf does not ship; "
            f"--unofficial-ok accepts them) — {what}: {verdict}"
        )
        return 1
    if v.state == Signature.SIGNED:
        print(f"certify verify: OK ({Signature.SIGNED} with {args.pubkey}) — {what}: {verdict}")
        return 0
    if v.state == Signature.UNSIGNED:
        print(f"certify verify: OK ({Signature.UNSIGNED}) — {what}: {verdict}")
        return 0
    if v.state == Signature.NOT_CHECKED and args.unsigned_ok:
        print(f"certify verify: OK ({Signature.NOT_CHECKED}; accepted by --unsigned-ok) — {what}: {verdict}")
        return 0
    print(
        f"certify verify: NOT VERIFIED ({v.state}: give --pubkey, or --unsigned-ok to accept the digests "
        f"alone) — {what}: {verdict}"
    )
    return 1
