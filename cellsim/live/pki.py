"""The cell's keys: a certificate authority and one certificate per role, for mutual TLS on Zenoh.

``cellsim keys init DIR`` writes::

    DIR/ca.pem            the cell CA's certificate: every process trusts it, and only it
    DIR/ca.key            the CA's private key: only to issue certificates; keep it off the cell network
    DIR/<role>.pem        a role's certificate (common name: the role), signed by the CA
    DIR/<role>.key        its private key (mode 0600)
    DIR/can.key           the cell's CAN key (128 bits, hex; mode 0600): authenticated CAN frames'
                          keys are derived from it (``cellsim/bridges/secoc.py``)
    DIR/opcua-bridge.*    the bridge's and the PLC's OPC UA application certificates and keys (RSA,
    DIR/opcua-plc.*       as OPC UA's Basic256Sha256 needs; ``cellsim/bridges/opcua.py``)

A process needs ``ca.pem`` and its own role's pair, nothing else: copy only those
to the machine that runs it (and ``can.key`` to the bridge daemon's, where its
devices authenticate their frames). The twin's access control (:mod:`cellsim.live.access`)
grants each role what its common name allows. Keys are ECDSA P-256.

**Only the twin can be a server.** The twin's certificate alone names hosts
(``localhost``, 127.0.0.1, ::1 and any ``--host``) and alone may authenticate a
TLS server (extended key usage ``serverAuth``); every other role's certificate
names no host and is for TLS clients only (``clientAuth``). A client checks the
server's certificate against the host it dials (``verify_name_on_connect``), so a
process holding any other role's key, the observer's say, cannot pose as the twin:
its certificate names no host and is no server's (docs/security.md, "Roles").
"""

from __future__ import annotations

import datetime
import ipaddress
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

ROLES = ("twin", "bridge", "emulator", "robot", "engineer", "observer")
"""One certificate each; a process runs as exactly one (docs/security.md, "Roles")."""
SERVER_ROLE = "twin"
"""The one role whose certificate names hosts and may serve TLS: every other process connects to it."""

DEFAULT_HOSTS = ("localhost", "127.0.0.1", "::1")
DEFAULT_DAYS = 365
CAN_KEY = "can.key"
OPCUA_URI = {"bridge": "urn:cellsim:bridge", "plc": "urn:cellsim:plc"}
"""The OPC UA application URI of each side of a PLC's link, named in its certificate."""
ENVIRONMENT = "CELLSIM_KEYS"
"""Environment variable naming the keys folder when ``--keys`` is not given."""


class KeysError(ValueError):
    """Missing, unreadable or mismatched key files (the message is one line)."""


@dataclass(frozen=True)
class RoleFiles:
    """The files one process needs: the CA to trust, its certificate and private key."""

    ca: Path
    certificate: Path
    key: Path


def default_keys_dir() -> Path:
    """``$CELLSIM_KEYS``, else ``$XDG_CONFIG_HOME/cellsim/keys`` (``~/.config/cellsim/keys``)."""
    if os.environ.get(ENVIRONMENT):
        return Path(os.environ[ENVIRONMENT])
    base = Path(os.environ.get("XDG_CONFIG_HOME") or Path.home() / ".config")
    return base / "cellsim" / "keys"


def role_files(folder: Path, role: str) -> RoleFiles:
    """A role's files in ``folder``, all present, or one error saying how to make them."""
    if role not in ROLES:
        raise KeysError(f"{role!r} is no role (expected one of: {', '.join(ROLES)})")
    files = RoleFiles(folder / "ca.pem", folder / f"{role}.pem", folder / f"{role}.key")
    missing = [p.name for p in (files.ca, files.certificate, files.key) if not p.is_file()]
    if missing:
        raise KeysError(f"{folder}: no {', '.join(missing)} for the {role} role "
                        f"(create the cell's keys with: cellsim keys init {folder})")
    return files


def check_pinned(folder: Path) -> None:
    """Refuse keys made before roles were pinned: a certificate in ``folder`` of another role than the
    twin's that names a host or may serve TLS could pose as the twin (rotate: a new folder)."""
    from cryptography import x509
    from cryptography.x509.oid import ExtendedKeyUsageOID, ExtensionOID

    for role in ROLES:
        path = folder / f"{role}.pem"
        if role == SERVER_ROLE or not path.is_file():
            continue
        try:
            cert = x509.load_pem_x509_certificate(path.read_bytes())
        except (OSError, ValueError) as e:
            raise KeysError(f"{path}: not a PEM certificate ({e})") from None
        extensions = {e.oid: e.value for e in cert.extensions}
        usages = extensions.get(ExtensionOID.EXTENDED_KEY_USAGE, ())
        if ExtensionOID.SUBJECT_ALTERNATIVE_NAME in extensions or ExtendedKeyUsageOID.SERVER_AUTH in usages:
            raise KeysError(f"{path}: the {role}'s certificate may serve TLS as the twin does (keys made before roles "
                            f"were pinned): make new keys with cellsim keys init NEW_FOLDER and use them")


def can_key(folder: Path) -> bytes:
    """The cell's CAN key (16 bytes) from ``folder``, or one error saying what is wrong with it."""
    path = folder / CAN_KEY
    try:
        text = path.read_text().strip()
    except FileNotFoundError:
        raise KeysError(f"{folder}: no {CAN_KEY}, the key of authenticated CAN frames (keys made by cellsim keys init "
                        "before it had one: create a new folder with cellsim keys init)") from None
    except (OSError, UnicodeDecodeError) as e:
        raise KeysError(f"{path}: cannot read it ({getattr(e, 'strerror', None) or e})") from None
    try:
        key = bytes.fromhex(text)
    except ValueError:
        key = b""
    if len(key) != 16:
        raise KeysError(f"{path}: not a 128-bit key (expected 32 hexadecimal digits on one line)")
    return key


def init_keys(folder: Path, hosts: tuple[str, ...] = (), days: int = DEFAULT_DAYS,
              now: datetime.datetime | None = None) -> list[Path]:
    """Create a CA and every role's certificate in ``folder``, which must not hold keys yet.

    All files appear at once (a folder renamed into place): a crash or a concurrent
    ``init`` leaves either no keys or one complete set, never a mix. Returns the files.
    """
    if folder.exists() and any(folder.iterdir()):
        raise KeysError(f"{folder}: not empty; keys are never overwritten (choose a new folder to rotate them)")
    if not 1 <= days <= 36500:
        raise KeysError(f"--days {days}: expected 1 to 36500")
    names = _subject_names([*DEFAULT_HOSTS, *hosts])
    now = now or datetime.datetime.now(datetime.timezone.utc)
    folder.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{folder.name}-", dir=folder.parent))
    try:
        ca_key, ca_cert = _certificate_authority(now, days)
        _write(staging / "ca.pem", _pem_certificate(ca_cert), private=False)
        _write(staging / "ca.key", _pem_key(ca_key), private=True)
        for role in ROLES:
            key, cert = _role_certificate(role, ca_key, ca_cert, names if role == SERVER_ROLE else None, now, days)
            _write(staging / f"{role}.pem", _pem_certificate(cert), private=False)
            _write(staging / f"{role}.key", _pem_key(key), private=True)
        _write(staging / CAN_KEY, os.urandom(16).hex().encode() + b"\n", private=True)
        for name in OPCUA_URI:  # OPC UA's RSA application certificates (a PLC's link)
            make_opcua_pair(staging, name)
        os.chmod(staging, 0o700)
        if folder.exists():
            folder.rmdir()  # empty (checked above); a concurrent init that got there first makes this fail
        os.rename(staging, folder)
    except OSError as e:
        shutil.rmtree(staging, ignore_errors=True)
        if folder.is_dir() and (folder / "ca.pem").is_file():
            raise KeysError(f"{folder}: another process created keys there at the same time") from None
        raise KeysError(f"{folder}: cannot write keys ({e.strerror or e})") from None
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return sorted(folder.iterdir())


def ensure_keys(folder: Path) -> bool:
    """First use: create the keys if ``folder`` does not exist yet (True if created). A folder made
    at the same moment by another process is used as it is."""
    if folder.exists():
        return False
    try:
        init_keys(folder)
    except KeysError:
        if (folder / "ca.pem").is_file():
            return False
        raise
    return True


def describe(folder: Path) -> list[str]:
    """One line per certificate (its role, common name and expiry), and one for the CAN key
    (``cellsim keys show``)."""
    from cryptography import x509
    from cryptography.x509.oid import NameOID

    lines = []
    for path in sorted(folder.glob("*.pem")):
        try:
            cert = x509.load_pem_x509_certificate(path.read_bytes())
        except (OSError, ValueError) as e:
            raise KeysError(f"{path}: not a PEM certificate ({e})") from None
        cn = cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)
        lines.append(f"{path.stem:<9} CN={cn[0].value if cn else '?':<22} expires {cert.not_valid_after_utc:%Y-%m-%d}")
    if (folder / CAN_KEY).is_file():
        can_key(folder)  # readable and well formed, or the error says why
        lines.append(f"{'can':<9} AES-128 key of authenticated CAN frames (never expires: rotate with the folder)")
    return lines


# -- X.509 -----------------------------------------------------------------------------


def _subject_names(hosts):
    from cryptography import x509

    names, seen = [], set()
    for host in hosts:
        if host in seen:
            continue
        seen.add(host)
        try:
            names.append(x509.IPAddress(ipaddress.ip_address(host)))
        except ValueError:
            if not host or any(c.isspace() for c in host):
                raise KeysError(f"--host {host!r}: expected a host name or an IP address") from None
            names.append(x509.DNSName(host))
    return names


def _certificate_authority(now, days):
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.ORGANIZATION_NAME, "cellsim"),
                      x509.NameAttribute(NameOID.COMMON_NAME, "cellsim cell CA")])
    cert = (
        x509.CertificateBuilder()
        .subject_name(name).issuer_name(name).public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=days))
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(x509.KeyUsage(digital_signature=False, content_commitment=False, key_encipherment=False,
                                     data_encipherment=False, key_agreement=False, key_cert_sign=True,
                                     crl_sign=True, encipher_only=False, decipher_only=False), critical=True)
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
        .sign(key, hashes.SHA256())
    )
    return key, cert


def _role_certificate(role, ca_key, ca_cert, names, now, days):
    """A role's certificate: a server's (``names``: its hosts, ``serverAuth`` and ``clientAuth``) for the
    twin, a client's (no host, ``clientAuth`` only) for every other role (``names`` None)."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    key = ec.generate_private_key(ec.SECP256R1())
    cert = (
        x509.CertificateBuilder()
        .subject_name(x509.Name([x509.NameAttribute(NameOID.ORGANIZATION_NAME, "cellsim"),
                                 x509.NameAttribute(NameOID.COMMON_NAME, role)]))
        .issuer_name(ca_cert.subject).public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=days))
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(x509.KeyUsage(digital_signature=True, content_commitment=False, key_encipherment=False,
                                     data_encipherment=False, key_agreement=False, key_cert_sign=False,
                                     crl_sign=False, encipher_only=False, decipher_only=False), critical=True)
        .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), critical=False)
    )
    if names is None:  # a client only: no host to be reached at, no server's key usage
        cert = cert.add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.CLIENT_AUTH]), critical=False)
    else:  # the twin: a server (the router) and, behind another twin's router, a client
        cert = (cert.add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]),
                                   critical=False)
                .add_extension(x509.SubjectAlternativeName(names), critical=False))
    return key, cert.sign(ca_key, hashes.SHA256())


def _pem_certificate(cert) -> bytes:
    from cryptography.hazmat.primitives import serialization

    return cert.public_bytes(serialization.Encoding.PEM)


def _pem_key(key) -> bytes:
    from cryptography.hazmat.primitives import serialization

    return key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                             serialization.NoEncryption())


def _write(path: Path, data: bytes, private: bool) -> None:
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600 if private else 0o644)
    with os.fdopen(fd, "wb") as f:
        f.write(data)


# -- OPC UA (a PLC's link: cellsim.bridges.opcua) -----------------------------------------------
def opcua_files(folder: Path, name: str) -> tuple[Path, Path]:
    """(certificate, private key) of ``name`` (``bridge`` or ``plc``) in the keys ``folder``, made (RSA 2048,
    self-signed, naming its application URI) if the folder has none yet."""
    import fcntl

    certificate, key = folder / f"opcua-{name}.pem", folder / f"opcua-{name}.key"
    if certificate.is_file() and key.is_file():
        return certificate, key
    folder.mkdir(parents=True, exist_ok=True)
    with open(folder / ".opcua.lock", "w") as lock:  # two processes starting at once make one pair, not two
        fcntl.flock(lock, fcntl.LOCK_EX)
        if certificate.is_file() and not key.is_file():  # a certificate given without its key is never replaced
            raise OSError(f"{certificate} has no key beside it ({key.name}): put it there, or remove the certificate "
                          "to have a new pair made")
        if not (certificate.is_file() and key.is_file()):
            make_opcua_pair(folder, name)  # (the key first, the certificate last: a pair is there once both are)
    return certificate, key


def opcua_peer_certificate(folder: Path, name: str) -> Path:
    """The other side's OPC UA certificate (``name``: ``bridge`` or ``plc``) in the keys ``folder``: its
    ``opcua-<name>.pem`` as given (the daemon's machine holds the PLC's certificate, not its key); a pair is made
    only where neither is there (both sides on one machine, first use)."""
    certificate = folder / f"opcua-{name}.pem"
    return certificate if certificate.is_file() else opcua_files(folder, name)[0]


def make_opcua_pair(folder: Path, name: str) -> None:
    """Write ``opcua-<name>.pem`` and ``.key`` in ``folder`` (each file appears whole)."""
    from asyncua.crypto.cert_gen import (dump_private_key_as_pem, generate_private_key,
                                         generate_self_signed_app_certificate)
    from cryptography import x509
    from cryptography.hazmat.primitives import serialization
    from cryptography.x509.oid import ExtendedKeyUsageOID

    private = generate_private_key()
    usage = ExtendedKeyUsageOID.SERVER_AUTH if name == "plc" else ExtendedKeyUsageOID.CLIENT_AUTH
    cert = generate_self_signed_app_certificate(
        private, f"cellsim {name}", {}, [x509.UniformResourceIdentifier(OPCUA_URI[name]), x509.DNSName("localhost")],
        [usage], days=3650)
    certificate, key = folder / f"opcua-{name}.pem", folder / f"opcua-{name}.key"
    for path, data, mode in ((key, dump_private_key_as_pem(private), 0o600),
                             (certificate, cert.public_bytes(serialization.Encoding.PEM), 0o644)):
        handle, staging = tempfile.mkstemp(prefix=f".{path.name}-", dir=folder)
        with os.fdopen(handle, "wb") as f:
            f.write(data)
        os.chmod(staging, mode)
        os.replace(staging, path)
