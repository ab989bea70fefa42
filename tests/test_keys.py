"""``cellsim keys``: the cell's CA and a certificate per role, read back with OpenSSL; keys made on first use."""

from __future__ import annotations

import os
import shutil
import stat
import subprocess
import sys

import pytest
from conftest import ROOT

from cellsim.live.pki import ROLES

needs_openssl = pytest.mark.skipif(shutil.which("openssl") is None, reason="the openssl command reads the files back")


def cellsim(*args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cellsim", *args], capture_output=True, text=True, timeout=120,
                          cwd=ROOT, env=env)


def openssl(*args: str) -> str:
    done = subprocess.run(["openssl", *args], capture_output=True, text=True, timeout=30)
    assert done.returncode == 0, done.stderr
    return done.stdout


@needs_openssl
def test_init_makes_a_ca_and_one_certificate_per_role_that_openssl_verifies(tmp_path):
    folder = tmp_path / "keys"
    done = cellsim("keys", "init", str(folder), "--host", "cell-twin.local", "--host", "10.1.2.3", "--days", "30")
    assert done.returncode == 0, done.stderr
    assert sorted(p.name for p in folder.iterdir()) == sorted(
        ["ca.pem", "ca.key", "can.key", *[f"{r}.pem" for r in ROLES], *[f"{r}.key" for r in ROLES],
         *[f"opcua-{side}.{ext}" for side in ("bridge", "plc") for ext in ("pem", "key")]])
    for side, usage in (("bridge", "TLS Web Client Authentication"), ("plc", "TLS Web Server Authentication")):
        # OPC UA's application certificates: RSA (Basic256Sha256), naming the application's URI, their key theirs
        text = openssl("x509", "-in", str(folder / f"opcua-{side}.pem"), "-noout", "-text")
        assert "rsaEncryption" in text and f"URI:urn:cellsim:{side}" in text and usage in text
        assert openssl("pkey", "-in", str(folder / f"opcua-{side}.key"), "-pubout") == openssl(
            "x509", "-in", str(folder / f"opcua-{side}.pem"), "-noout", "-pubkey")
    for key in folder.glob("*.key"):
        assert stat.S_IMODE(key.stat().st_mode) == 0o600, key  # private keys readable by their owner only
    assert "CA:TRUE" in openssl("x509", "-in", str(folder / "ca.pem"), "-noout", "-text")
    for role in ROLES:
        cert = str(folder / f"{role}.pem")
        assert openssl("verify", "-CAfile", str(folder / "ca.pem"), cert).strip().endswith("OK")
        assert f"CN = {role}" in openssl("x509", "-in", cert, "-noout", "-subject", "-nameopt", "oneline")
        text = openssl("x509", "-in", cert, "-noout", "-text")
        if role == "twin":  # the one server: it names the hosts clients dial, and may serve TLS
            for name in ("DNS:localhost", "IP Address:127.0.0.1", "DNS:cell-twin.local", "IP Address:10.1.2.3"):
                assert name in text, (role, name)
            assert "TLS Web Server Authentication, TLS Web Client Authentication" in text
        else:  # a client only: no host, no server's key usage, so it cannot pose as the twin
            assert "Subject Alternative Name" not in text and "Server Authentication" not in text, role
            assert "TLS Web Client Authentication" in text
            # OpenSSL agrees: the twin's certificate is a TLS server's, this one is not
            assert openssl("verify", "-CAfile", str(folder / "ca.pem"), "-purpose", "sslclient", cert).strip().endswith("OK")
            refused = subprocess.run(["openssl", "verify", "-CAfile", str(folder / "ca.pem"), "-purpose", "sslserver", cert],
                                     capture_output=True, text=True, timeout=30)
            assert refused.returncode != 0 and "unsuitable certificate purpose" in refused.stdout + refused.stderr
        # the key is the certificate's
        assert openssl("pkey", "-in", str(folder / f"{role}.key"), "-pubout") == openssl("x509", "-in", cert, "-noout", "-pubkey")
    shown = cellsim("keys", "show", str(folder))
    assert shown.returncode == 0 and "observer  CN=observer" in shown.stdout


def test_keys_are_never_overwritten_and_bad_input_writes_nothing(tmp_path):
    folder = tmp_path / "keys"
    assert cellsim("keys", "init", str(folder)).returncode == 0
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    again = cellsim("keys", "init", str(folder))
    assert again.returncode == 2 and "never overwritten" in again.stderr and again.stderr.count("\n") == 1
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before
    for args, expected in ((["--host", "a b"], "--host 'a b'"), (["--days", "0"], "--days 0")):
        bad = cellsim("keys", "init", str(tmp_path / "other"), *args)
        assert bad.returncode == 2 and expected in bad.stderr
        assert not (tmp_path / "other").exists() and [p.name for p in tmp_path.iterdir()] == ["keys"]


def test_a_networked_command_makes_the_default_keys_on_first_use_and_says_so(tmp_path):
    env = {k: v for k, v in os.environ.items() if k != "CELLSIM_KEYS"}
    env["XDG_CONFIG_HOME"] = str(tmp_path / "config")
    done = cellsim("twin-mode", "robot", "shadow", "--connect", "tls/127.0.0.1:9", "--timeout", "0.5", env=env)
    assert done.returncode == 2 and "no running twin reachable" in done.stderr  # nothing listens there
    folder = tmp_path / "config" / "cellsim" / "keys"
    assert f"created the cell's keys in {folder}" in done.stderr
    assert (folder / "engineer.pem").is_file() and (folder / "ca.key").is_file()
    again = cellsim("twin-mode", "robot", "shadow", "--connect", "tls/127.0.0.1:9", "--timeout", "0.5", env=env)
    assert "created" not in again.stderr  # the same keys from now on


def test_insecure_warns_and_plain_tcp_without_it_is_refused(tmp_path):
    plain = cellsim("twin-mode", "robot", "shadow", "--connect", "tcp/127.0.0.1:9", "--timeout", "0.5")
    assert plain.returncode == 2 and "tcp/ has no encryption or authentication" in plain.stderr
    insecure = cellsim("twin-mode", "robot", "shadow", "--connect", "tcp/127.0.0.1:9", "--timeout", "0.5", "--insecure")
    assert insecure.returncode == 2 and "warning: --insecure" in insecure.stderr
    remote = cellsim("twin-mode", "robot", "shadow", "--connect", "tcp/192.0.2.7:7447", "--insecure")
    assert remote.returncode == 2 and "loopback only" in remote.stderr


def test_a_keys_folder_without_the_roles_files_is_said_as_such_not_as_an_absent_twin(tmp_path):
    done = cellsim("twin-mode", "robot", "shadow", "--keys", str(tmp_path / "none"), "--timeout", "0.5")
    assert done.returncode == 2
    assert "no ca.pem, engineer.pem, engineer.key for the engineer role" in done.stderr
    assert f"cellsim keys init {tmp_path / 'none'}" in done.stderr and "no running twin" not in done.stderr
