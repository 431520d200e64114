"""Certificates for authenticated runs: a CA and one certificate per identity (CN = identity).

Zenoh's mutual TLS authenticates every session with a certificate signed by the fleet CA; the
router's access control (bus_schemas.acl) then matches the certificate's common name (CN).

Layout written (the same as deploy/security/gen-certs.sh, so deploy/zenoh's configs find it)::

    <dir>/ca/ca.pem, ca.key          the CA (ca.key never leaves the machine that made it)
    <dir>/router/{ca,cert,key}.pem   the router: serverAuth + clientAuth, SAN = router hosts
    <dir>/<cn>/{ca,cert,key}.pem     each identity: clientAuth, CN = <cn> (robot.r1, operator...)

Keys are ECDSA P-256 (rustls accepts them; generating one takes ~1 ms), private keys PKCS#8 PEM,
mode 0600. :func:`make_run_pki` makes an ephemeral PKI for one local run (valid for a day);
``formation certs`` makes a deployment's (kept CA, 825 days, adding identities later).
"""

from __future__ import annotations

import argparse
import datetime as dt
import ipaddress
import os
import sys
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from bus_schemas import acl
from bus_schemas.session import LEASE_MS

ROUTER_CN = "router"
DEFAULT_ROUTER_HOSTS = ("localhost", "127.0.0.1")
_ORG = "formation"


@dataclass(frozen=True)
class CertPaths:
    """The PEM files of one identity: the CA to trust, its certificate and its private key."""

    ca: Path
    cert: Path
    key: Path

    def tls(self) -> acl.TlsFiles:
        """The same paths as bus_schemas.acl.TlsFiles (for router_config / client_config)."""
        return acl.TlsFiles(ca=str(self.ca), cert=str(self.cert), key=str(self.key))


@dataclass(frozen=True)
class RunPki:
    """A PKI on disk: its directory, the CA, the router's files and each identity's (by CN)."""

    root: Path
    ca: Path
    router: CertPaths
    identities: dict[str, CertPaths]


def _new_key() -> ec.EllipticCurvePrivateKey:
    return ec.generate_private_key(ec.SECP256R1())


def _write_key(path: Path, key: ec.EllipticCurvePrivateKey) -> None:
    data = key.private_bytes(
        serialization.Encoding.PEM,
        serialization.PrivateFormat.PKCS8,
        serialization.NoEncryption(),
    )
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(data)
    os.chmod(path, 0o600)


def _write_cert(path: Path, cert: x509.Certificate) -> None:
    path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    os.chmod(path, 0o644)


def _name(cn: str) -> x509.Name:
    return x509.Name(
        [
            x509.NameAttribute(NameOID.ORGANIZATION_NAME, _ORG),
            x509.NameAttribute(NameOID.COMMON_NAME, cn),
        ]
    )


def _san(hosts: Iterable[str]) -> list[x509.GeneralName]:
    out: list[x509.GeneralName] = []
    for h in hosts:
        try:
            out.append(x509.IPAddress(ipaddress.ip_address(h)))
        except ValueError:
            out.append(x509.DNSName(h))
    return out


def _load_or_make_ca(
    root: Path, days: int, force: bool
) -> tuple[ec.EllipticCurvePrivateKey, x509.Certificate]:
    ca_dir = root / "ca"
    key_path, pem_path = ca_dir / "ca.key", ca_dir / "ca.pem"
    if not force and key_path.is_file() and pem_path.is_file():
        key = serialization.load_pem_private_key(key_path.read_bytes(), password=None)
        if not isinstance(key, ec.EllipticCurvePrivateKey):
            raise ValueError(f"{key_path}: not an EC private key")
        return key, x509.load_pem_x509_certificate(pem_path.read_bytes())
    ca_dir.mkdir(parents=True, exist_ok=True)
    os.chmod(ca_dir, 0o700)
    key = _new_key()
    now = dt.datetime.now(dt.UTC)
    name = _name("formation fleet CA")
    cert = (
        x509.CertificateBuilder()
        .subject_name(name)
        .issuer_name(name)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - dt.timedelta(minutes=5))
        .not_valid_after(now + dt.timedelta(days=days))
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(
            x509.KeyUsage(
                digital_signature=False,
                content_commitment=False,
                key_encipherment=False,
                data_encipherment=False,
                key_agreement=False,
                key_cert_sign=True,
                crl_sign=True,
                encipher_only=False,
                decipher_only=False,
            ),
            critical=True,
        )
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
        .sign(key, hashes.SHA256())
    )
    _write_key(key_path, key)
    _write_cert(pem_path, cert)
    return key, cert


def _issue(
    out_dir: Path,
    cn: str,
    ca_key: ec.EllipticCurvePrivateKey,
    ca_cert: x509.Certificate,
    *,
    days: int,
    server_hosts: Sequence[str] = (),
    force: bool,
) -> CertPaths:
    paths = CertPaths(out_dir / "ca.pem", out_dir / "cert.pem", out_dir / "key.pem")
    if not force and paths.cert.is_file() and paths.key.is_file():
        return paths
    out_dir.mkdir(parents=True, exist_ok=True)
    key = _new_key()
    now = dt.datetime.now(dt.UTC)
    usages = [ExtendedKeyUsageOID.CLIENT_AUTH]
    if server_hosts:
        usages.insert(0, ExtendedKeyUsageOID.SERVER_AUTH)
    builder = (
        x509.CertificateBuilder()
        .subject_name(_name(cn))
        .issuer_name(ca_cert.subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - dt.timedelta(minutes=5))
        .not_valid_after(now + dt.timedelta(days=days))
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(
            x509.KeyUsage(
                digital_signature=True,
                content_commitment=False,
                key_encipherment=False,
                data_encipherment=False,
                key_agreement=False,
                key_cert_sign=False,
                crl_sign=False,
                encipher_only=False,
                decipher_only=False,
            ),
            critical=True,
        )
        .add_extension(x509.ExtendedKeyUsage(usages), critical=False)
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
        .add_extension(
            x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()),
            critical=False,
        )
    )
    if server_hosts:
        builder = builder.add_extension(
            x509.SubjectAlternativeName(_san(server_hosts)), critical=False
        )
    cert = builder.sign(ca_key, hashes.SHA256())
    _write_key(paths.key, key)
    _write_cert(paths.cert, cert)
    _write_cert(paths.ca, ca_cert)
    return paths


def _check_cn(cn: str) -> str:
    if cn in (ROUTER_CN, "ca"):
        raise ValueError(f"{cn!r} is reserved")
    acl.Identity.parse(cn)  # raises ValueError for anything that is not an identity's CN
    return cn


def make_pki(
    root: str | Path,
    cns: Iterable[str],
    *,
    router_hosts: Sequence[str] = DEFAULT_ROUTER_HOSTS,
    days: int = 825,
    force: bool = False,
) -> RunPki:
    """Make (or extend) the PKI in ``root``: the CA (kept if present unless ``force``), the
    router's certificate and one per CN in ``cns`` (existing ones kept unless ``force``)."""
    cn_list = [_check_cn(c) for c in cns]
    if not router_hosts:
        raise ValueError("at least one router host name or address is needed")
    if days < 1:
        raise ValueError("days must be >= 1")
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    ca_key, ca_cert = _load_or_make_ca(root, days, force)
    router = _issue(
        root / ROUTER_CN,
        ROUTER_CN,
        ca_key,
        ca_cert,
        days=days,
        server_hosts=router_hosts,
        force=force,
    )
    identities = {
        cn: _issue(root / cn, cn, ca_key, ca_cert, days=days, force=force) for cn in cn_list
    }
    return RunPki(root=root, ca=root / "ca" / "ca.pem", router=router, identities=identities)


def make_run_pki(root: str | Path, identities: Iterable[acl.Identity | str]) -> RunPki:
    """An ephemeral PKI for one local run: a fresh CA and certificates valid for one day, for a
    router on ``localhost`` / ``127.0.0.1`` and each of ``identities`` (Identity or CN)."""
    cns = [i.cn if isinstance(i, acl.Identity) else i for i in identities]
    return make_pki(root, cns, router_hosts=DEFAULT_ROUTER_HOSTS, days=1, force=True)


@dataclass(frozen=True)
class RunConfigs:
    """The Zenoh config files of an authenticated local run: the router's, and each identity's
    client config by CN (pass each as ``--zenoh-config`` to that process)."""

    pki: RunPki
    router: Path
    clients: dict[str, Path]
    endpoint: str


def write_run_configs(
    root: str | Path,
    identities: Sequence[acl.Identity],
    *,
    port: int,
    fleet: str = "demo",
    lease_ms: int = LEASE_MS,
) -> RunConfigs:
    """Everything an authenticated local run needs, under ``root``: an ephemeral PKI
    (:func:`make_run_pki`) for ``identities``, the router config (``tls/127.0.0.1:<port>``,
    mTLS, access control of ``identities`` for ``fleet``) and one client config per identity
    (connecting to ``tls/localhost:<port>``, failing at once if the router is absent).

    A launcher starts ``formation router --zenoh-config <router>`` and every process with
    ``--zenoh-config <clients[cn]>`` and no ``--endpoint`` (the file's is the TLS one)."""
    root = Path(root)
    pki = make_run_pki(root / "pki", identities)
    conf_dir = root / "zenoh"
    conf_dir.mkdir(parents=True, exist_ok=True)
    router_conf = acl.router_config(
        identities,
        pki.router.tls(),
        fleet=fleet,
        listen=(f"tls/127.0.0.1:{port}",),
        lease_ms=lease_ms,
    )
    router_path = conf_dir / "router.json5"
    router_path.write_text(acl.to_json5(router_conf, "authenticated local run: router"))
    endpoint = f"tls/localhost:{port}"
    clients: dict[str, Path] = {}
    for ident in identities:
        conf = acl.client_config(
            pki.identities[ident.cn].tls(),
            connect=(endpoint,),
            lease_ms=lease_ms,
            retry_forever=False,
        )
        path = conf_dir / f"{ident.cn}.json5"
        path.write_text(acl.to_json5(conf, f"authenticated local run: {ident.cn}"))
        clients[ident.cn] = path
    return RunConfigs(pki=pki, router=router_path, clients=clients, endpoint=endpoint)


def main(argv: list[str] | None = None) -> int:
    """``formation certs``: make or extend a deployment's certificates."""
    parser = argparse.ArgumentParser(
        prog="formation certs",
        description="Make the fleet CA and one certificate per identity (CN = identity, as the "
        "access control of `formation acl` expects). Existing files are kept unless --force.",
    )
    parser.add_argument("-o", "--out", required=True, help="directory (keep ca/ca.key private)")
    parser.add_argument("--router-host", action="append", default=[], metavar="NAME_OR_IP")
    parser.add_argument("--robots", type=acl._csv, default=[], help="r1,r2,r3")
    parser.add_argument(
        "--coordinators", type=acl._csv, default=list(acl.DEPLOY_COORDINATORS), help="main,standby"
    )
    parser.add_argument(
        "--operators", type=acl._csv, default=[], help="operator names (default: CN operator)"
    )
    parser.add_argument(
        "--observers", type=acl._csv, default=[], help="observer names (default: CN observer)"
    )
    parser.add_argument(
        "--no-localization", action="store_true", help="no localization certificate"
    )
    parser.add_argument("--plant", action="store_true", help="also a plant (simulator) identity")
    parser.add_argument(
        "--no-ros2", action="store_true", help="no certificate for the ROS 2 bridge (CN ros2)"
    )
    parser.add_argument("--cn", action="append", default=[], help="any other identity CN")
    parser.add_argument("--days", type=int, default=825)
    parser.add_argument("--force", action="store_true", help="replace existing files")
    ns = parser.parse_args(argv)
    try:
        idents = [acl.robot(r) for r in ns.robots]
        idents += [acl.coordinator(c) for c in ns.coordinators]
        idents += [acl.Identity(acl.Kind.OPERATOR, n) for n in ns.operators or [""]]
        idents += [acl.Identity(acl.Kind.OBSERVER, n) for n in ns.observers or [""]]
        if not ns.no_localization:
            idents.append(acl.Identity(acl.Kind.LOCALIZATION))
        if ns.plant:
            idents.append(acl.Identity(acl.Kind.PLANT))
        if not ns.no_ros2:
            idents.append(acl.Identity(acl.Kind.ROS2))
        cns = [i.cn for i in idents] + [_check_cn(c) for c in ns.cn]
        pki = make_pki(
            ns.out,
            cns,
            router_hosts=ns.router_host or DEFAULT_ROUTER_HOSTS,
            days=ns.days,
            force=ns.force,
        )
    except ValueError as exc:
        print(f"formation certs: {exc}", file=sys.stderr)
        return 2
    print(f"{'CA':<24} {pki.ca}")
    print(f"{'router':<24} {pki.router.cert.parent}")
    for cn, paths in pki.identities.items():
        print(f"{cn:<24} {paths.cert.parent}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
