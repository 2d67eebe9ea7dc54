"""``zentrack certs --out DIR --nodes N [--sensors S]``: a CA and one key and certificate per process role for
secure mode.

Writes ``ca.pem`` and ``ca.key`` (keep the CA key off the hosts that run processes), and ``<role>.pem`` /
``<role>.key`` for ``router``, ``truth``, ``recorder``, ``viewer``, ``monitor``, ``node-0`` .. ``node-<N-1>``
and, for a scenario with sensors of their own (``[sensor_timing]``), ``sensor-0`` .. ``sensor-<S-1>``. The
common name is the role: the router's access control grants rights by it
(``zentrack.transport.secure``). Keys are ECDSA P-256 (PKCS#8, mode 0600); every certificate carries the
names ``localhost``, ``127.0.0.1`` and any ``--host`` given, so it serves as the router's server certificate
and as a client certificate alike.
"""
from __future__ import annotations

import argparse
import datetime
import ipaddress
import os
from pathlib import Path

from zentrack.common.argtypes import host_name, int_in
from zentrack.common.atomic import write_bytes_atomically
from zentrack.transport.keys import sensor_name
from zentrack.transport.secure import SERVICE_ROLES


def _key():
    from cryptography.hazmat.primitives.asymmetric import ec

    return ec.generate_private_key(ec.SECP256R1())


def _write(path: Path, data: bytes, private: bool) -> None:
    write_bytes_atomically(path, data, 0o600 if private else 0o644)


def _save(folder: Path, name: str, key, cert) -> None:
    from cryptography.hazmat.primitives import serialization

    _write(folder / f"{name}.key", key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                                     serialization.NoEncryption()), private=True)
    _write(folder / f"{name}.pem", cert.public_bytes(serialization.Encoding.PEM), private=False)


def _usage(ca: bool):
    from cryptography import x509

    return x509.KeyUsage(digital_signature=True, key_cert_sign=ca, crl_sign=ca, content_commitment=False,
                         key_encipherment=False, data_encipherment=False, key_agreement=False,
                         encipher_only=False, decipher_only=False)


def _names(hosts: list[str]):
    from cryptography import x509

    out: list = []
    for host in ["localhost", "127.0.0.1", *hosts]:
        try:
            out.append(x509.IPAddress(ipaddress.ip_address(host)))
        except ValueError:
            out.append(x509.DNSName(host))
    return x509.SubjectAlternativeName(out)


def make_certificates(folder: str | os.PathLike, nodes: int, days: int = 30, hosts: list[str] | None = None,
                      sensors: int = 0) -> list[str]:
    """Write the CA and every role's key and certificate into ``folder`` (:func:`run_roles`); returns the roles
    written."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    now = datetime.datetime.now(datetime.UTC)
    start, end = now - datetime.timedelta(minutes=5), now + datetime.timedelta(days=days)
    ca_key = _key()
    ca_name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "zentrack CA")])
    ca = (x509.CertificateBuilder().subject_name(ca_name).issuer_name(ca_name).public_key(ca_key.public_key())
          .serial_number(x509.random_serial_number()).not_valid_before(start).not_valid_after(end)
          .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
          .add_extension(_usage(ca=True), critical=True)
          .add_extension(x509.SubjectKeyIdentifier.from_public_key(ca_key.public_key()), critical=False)
          .sign(ca_key, hashes.SHA256()))
    _save(out, "ca", ca_key, ca)
    written = run_roles(nodes, sensors)
    names = _names(list(hosts or []))
    usage = x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH])
    for role in written:
        key = _key()
        cert = (x509.CertificateBuilder().subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, role)]))
                .issuer_name(ca_name).public_key(key.public_key()).serial_number(x509.random_serial_number())
                .not_valid_before(start).not_valid_after(end)
                .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
                .add_extension(_usage(ca=False), critical=True).add_extension(usage, critical=False)
                .add_extension(names, critical=False)
                .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), critical=False)
                .sign(ca_key, hashes.SHA256()))
        _save(out, role, key, cert)
    return written


def run_roles(nodes: int, sensors: int = 0, services: tuple[str, ...] = SERVICE_ROLES) -> list[str]:
    """The roles of a run of ``nodes`` trackers and ``sensors`` sensors of their own: ``services``, then
    ``node-<i>`` and ``sensor-<s>`` (:func:`~zentrack.transport.keys.sensor_name`)."""
    return [*services, *(f"node-{i}" for i in range(nodes)), *(sensor_name(s) for s in range(sensors))]


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, metavar="DIR", help="folder for ca.pem, ca.key and <role>.pem/.key")
    p.add_argument("--nodes", type=int_in(1, 1000, "nodes"), required=True, help="trackers: node-0 .. node-<N-1>")
    p.add_argument("--sensors", type=int_in(0, 1000, "sensors"), default=0,
                   help="sensors of their own ([sensor_timing]): sensor-0 .. sensor-<S-1> (default 0)")
    p.add_argument("--days", type=int_in(1, 3650, "days"), default=30, help="validity (default 30 days)")
    p.add_argument("--host", action="append", default=[], metavar="NAME|IP", type=host_name,
                   help="another name the router is reached by (repeatable; localhost and 127.0.0.1 always)")


def run(args: argparse.Namespace) -> int:
    written = make_certificates(args.out, args.nodes, args.days, args.host, args.sensors)
    print(f"certificates for {len(written)} roles ({', '.join(written[:6])}{' ...' if len(written) > 6 else ''}) "
          f"and the CA in {args.out}; ca.key signs them: keep it off the hosts that run processes")
    return 0


def add_secure_argument(p: argparse.ArgumentParser, without_folder: str) -> None:
    """``--secure [CERTS_DIR]``, one spelling for every cluster command: with a folder, that folder's
    certificates; without, ``without_folder`` says where they come from."""
    p.add_argument("--secure", nargs="?", const="", default=None, metavar="CERTS_DIR",
                   help="secure mode: every process a mutual-TLS client of a router that enforces access control by "
                        f"certificate; the certificates in CERTS_DIR (`zentrack certs`), {without_folder}")


def certificate_folder(secure: str | None, made_in: Path, roles: list[str]) -> str | None:
    """The certificate folder of ``--secure [CERTS_DIR]`` (None: not secure): ``made_in`` without a folder (the
    caller makes them there with :func:`make_certificates` once it owns that folder); a given folder must hold
    every one of ``roles`` (ValueError naming the first missing file, before anything starts)."""
    from zentrack.transport.secure import Identity

    if secure is None:
        return None
    if secure == "":
        return str(made_in.resolve())
    for role in roles:
        Identity(Path(secure), role).check()
    return str(Path(secure).resolve())
