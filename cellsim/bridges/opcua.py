"""OPC UA as the bridge speaks it to a PLC: how a field sits in a node, and the cell's OPC UA certificates.

One coding for both ends, the daemon's client (``cellsim.bridges.plc``) and the
emulated PLC's server (``cellsim.bridges.plc_server``):

* an enumerated field is its value's *code*, its position in the field's list
  (``cellsim modules KIND``), as an Int32; no value (a null command) is -1;
* a flag is a Boolean;
* a number is a Double; no value is NaN.

**Certificates.** OPC UA's Sign & Encrypt (``Basic256Sha256``) needs RSA
application instance certificates naming the application's URI. The cell's keys
folder (``cellsim keys init``, docs/security.md) holds one pair each for the
bridge (the client, ``opcua-bridge.pem``/``.key``) and the PLC
(``opcua-plc.pem``/``.key``: the emulated PLC's; for a real PLC, replace
``opcua-plc.pem`` with the certificate the PLC exports and put ``opcua-bridge.pem``
in the PLC's trust list). Each side trusts exactly the other's certificate: the
daemon refuses a server presenting another; the emulated PLC (asyncua's server) a session
created with another.
A pair missing from an older keys folder is made on first use
(``cellsim.live.pki.opcua_files``).
"""

from __future__ import annotations

import math
from pathlib import Path

from cellsim.live.pki import OPCUA_URI as APPLICATION_URI

NO_CODE = -1


def quiet_asyncua() -> None:
    """asyncua logs every connection step and certificate remark, and a lost server as tracebacks: none of it is
    said: a lost connection is the daemon's to say, once (the bridge and the emulated PLC say what counts themselves)."""
    import logging

    logging.getLogger("asyncua").setLevel(logging.CRITICAL)


class NodeValueError(ValueError):
    """A node's value the field cannot take (the message says which and why)."""


def variant_type(ctype):
    """The OPC UA variant type a field of ``ctype`` is carried as."""
    from asyncua import ua

    return {"enum": ua.VariantType.Int32, "bool": ua.VariantType.Boolean}.get(ctype.kind, ua.VariantType.Double)


def to_node(ctype, value):
    """A field's value (as the live format has it: a name, a bool, a number, None) as its node's value."""
    if ctype.kind == "enum":
        return NO_CODE if value is None else int(ctype.encode(value)[0])
    if ctype.kind == "bool":
        return bool(value)
    return math.nan if value is None else float(value)


def from_node(ctype, value, nullable: bool = False):
    """A node's value as the field's (NodeValueError for one it cannot take)."""
    if ctype.kind == "enum":
        if isinstance(value, bool) or not isinstance(value, int):
            raise NodeValueError(f"{value!r} is not an integer code")
        if value == NO_CODE and nullable:
            return None
        try:
            return ctype.enum.from_code(value).value
        except ValueError:
            raise NodeValueError(f"code {value} is not one of {', '.join(ctype.domain())}") from None
    if ctype.kind == "bool":
        if not isinstance(value, bool):
            raise NodeValueError(f"{value!r} is not a Boolean")
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise NodeValueError(f"{value!r} is not a number")
    if not math.isfinite(value):
        if nullable and math.isnan(value):
            return None
        raise NodeValueError(f"{value!r} is not a finite number")
    return float(value)


# -- certificates (made and kept with the cell's keys: cellsim.live.pki) -------------------------------
def load_certificate(path: Path):
    """The X.509 certificate in a PEM file."""
    from cryptography import x509

    return x509.load_pem_x509_certificate(path.read_bytes())


def pinned(expected):
    """An asyncua certificate validator accepting exactly the certificate ``expected``: any other peer is
    refused with BadCertificateUntrusted."""
    from asyncua import ua

    async def validate(certificate, application) -> None:
        if certificate != expected:
            raise ua.uaerrors.BadCertificateUntrusted()

    return validate
