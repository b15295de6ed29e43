"""Certificates for a run's own TLS (the Dask cluster of :mod:`fbaconf.harness.cluster`): a
certificate authority made for the run and one certificate it signed, with ``cryptography``
(RSA 2048, SHA-256, valid one day, for 127.0.0.1 and localhost), in a private folder."""
from __future__ import annotations

import datetime
import ipaddress
import os
import secrets
from pathlib import Path


def make_certificates(folder: Path, *, common_name: str = "fbaconf-run") -> dict[str, Path]:
    """A certificate authority and one certificate (and key) it signed, for 127.0.0.1 and
    localhost, written to ``folder`` (made private); returns the PEM paths: ca, cert, key."""
    from cryptography import x509  # noqa: PLC0415 (the cluster extra)
    from cryptography.hazmat.primitives import hashes, serialization  # noqa: PLC0415
    from cryptography.hazmat.primitives.asymmetric import rsa  # noqa: PLC0415
    from cryptography.x509.oid import NameOID  # noqa: PLC0415
    folder.mkdir(mode=0o700, parents=True, exist_ok=True)
    os.chmod(folder, 0o700)
    now = datetime.datetime.now(datetime.timezone.utc)

    def name(cn: str):
        return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn)])

    def cert(subject, issuer, public, signer, *, ca: bool):
        b = (x509.CertificateBuilder().subject_name(subject).issuer_name(issuer).public_key(public)
             .serial_number(x509.random_serial_number()).not_valid_before(now - datetime.timedelta(minutes=5))
             .not_valid_after(now + datetime.timedelta(days=1))
             .add_extension(x509.BasicConstraints(ca=ca, path_length=None), critical=True))
        if not ca:
            b = b.add_extension(x509.SubjectAlternativeName([x509.DNSName("localhost"),
                                                             x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]),
                                critical=False)
        return b.sign(signer, hashes.SHA256())

    ca_key = rsa.generate_private_key(public_exponent=65537, key_size=2048)
    ca_name = name(f"{common_name}-ca-{secrets.token_hex(4)}")
    ca = cert(ca_name, ca_name, ca_key.public_key(), ca_key, ca=True)
    key = rsa.generate_private_key(public_exponent=65537, key_size=2048)
    leaf = cert(name(common_name), ca_name, key.public_key(), ca_key, ca=False)
    paths = {"ca": folder / "ca.pem", "cert": folder / "cert.pem", "key": folder / "key.pem"}
    pem = serialization.Encoding.PEM
    for p, data in ((paths["ca"], ca.public_bytes(pem)), (paths["cert"], leaf.public_bytes(pem)),
                    (paths["key"], key.private_bytes(pem, serialization.PrivateFormat.PKCS8,
                                                     serialization.NoEncryption()))):
        fd = os.open(p, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        with os.fdopen(fd, "wb") as f:
            f.write(data)
    return paths
