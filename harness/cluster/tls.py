"""A run's own TLS secret, kept in memory (the Dask cluster of :mod:`fbaconf.harness.cluster`):
a certificate authority made for the run and one certificate it signed, with ``cryptography``
(RSA 2048, SHA-256, valid one day, for 127.0.0.1 and localhost).

Nothing is written to a file: a file of the lab's user is readable by every process of that
user, and whoever holds the certificate and its key joins the run's cluster. The authority's
own key is dropped once it has signed (nothing else is ever signed with it), so the run's
secret is the one certificate's key; the process holding it closes itself to the user's other
processes (:func:`nondumpable`), and hands the key to OpenSSL through an anonymous memory file
(:func:`memory_file`), never a path another process could open."""

from __future__ import annotations

import ctypes
import datetime
import ipaddress
import os
import secrets
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import NoReturn

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import rsa
from cryptography.x509.oid import NameOID

PR_GET_DUMPABLE, PR_SET_DUMPABLE = 3, 4


@dataclass(frozen=True, repr=False)
class RunCertificates:
    """PEM bytes: the authority's certificate (public), the certificate it signed and that
    certificate's private key (the secret)."""

    ca: bytes
    cert: bytes
    key: bytes

    def __repr__(self) -> str:  # never the key, in a log or a traceback
        return "RunCertificates(<in memory>)"

    def __reduce__(self) -> NoReturn:
        raise TypeError("the run's TLS key is not pickled: it stays in the memory of the process that made it")


def make_certificates(*, common_name: str = "fbaconf-run") -> RunCertificates:
    """A certificate authority and one certificate (and key) it signed, for 127.0.0.1 and
    localhost, as PEM bytes in memory; the authority's key is not kept."""
    now = datetime.datetime.now(datetime.UTC)

    def name(cn: str) -> x509.Name:
        return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn)])

    def cert(
        subject: x509.Name,
        issuer: x509.Name,
        public: rsa.RSAPublicKey,
        signer: rsa.RSAPrivateKey,
        *,
        ca: bool,
    ) -> x509.Certificate:
        b = (
            x509.CertificateBuilder()
            .subject_name(subject)
            .issuer_name(issuer)
            .public_key(public)
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=5))
            .not_valid_after(now + datetime.timedelta(days=1))
            .add_extension(x509.BasicConstraints(ca=ca, path_length=None), critical=True)
        )
        if not ca:
            b = b.add_extension(
                x509.SubjectAlternativeName(
                    [x509.DNSName("localhost"), x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]
                ),
                critical=False,
            )
        return b.sign(signer, hashes.SHA256())

    ca_key = rsa.generate_private_key(public_exponent=65537, key_size=2048)
    ca_name = name(f"{common_name}-ca-{secrets.token_hex(4)}")
    ca = cert(ca_name, ca_name, ca_key.public_key(), ca_key, ca=True)
    key = rsa.generate_private_key(public_exponent=65537, key_size=2048)
    leaf = cert(name(common_name), ca_name, key.public_key(), ca_key, ca=False)
    del ca_key
    pem = serialization.Encoding.PEM
    return RunCertificates(
        ca.public_bytes(pem),
        leaf.public_bytes(pem),
        key.private_bytes(pem, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()),
    )


def _prctl(option: int, value: int = 0) -> int:
    r = ctypes.CDLL(None, use_errno=True).prctl(option, value, 0, 0, 0)
    if r < 0:
        raise OSError(ctypes.get_errno(), f"prctl({option}) failed")
    return int(r)


def is_dumpable() -> bool:
    return bool(_prctl(PR_GET_DUMPABLE))


@contextmanager
def nondumpable() -> Iterator[None]:
    """This process non-dumpable for the block (``prctl(PR_SET_DUMPABLE, 0)``): another process
    of its user, without ``CAP_SYS_PTRACE``, can no longer read its ``/proc/<pid>/mem`` or
    ``environ``, open its descriptors through ``/proc/<pid>/fd`` or attach to it; children it
    forks inherit that. Dumpable again after, if it was — a run's key is of no use once its
    cluster is gone."""
    was = _prctl(PR_GET_DUMPABLE)
    _prctl(PR_SET_DUMPABLE, 0)
    try:
        yield
    finally:
        if was:
            _prctl(PR_SET_DUMPABLE, was)


@contextmanager
def memory_file(data: bytes) -> Iterator[str]:
    """A path to ``data`` that only this process can open, for the block: a memfd (a file in
    no filesystem) named through this process's own descriptor table (``/proc/self/fd/N``)."""
    fd = os.memfd_create("fbaconf-run-tls", os.MFD_CLOEXEC)
    try:
        view = memoryview(data)
        while view:
            view = view[os.write(fd, view) :]
        yield f"/proc/self/fd/{fd}"
    finally:
        os.close(fd)
