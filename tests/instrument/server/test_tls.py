"""TLS end to end: a server with a certificate, a client that trusts it (HTTP and the
event stream), and one that does not."""

from __future__ import annotations

import shutil
import subprocess

import pytest

from instrument.client import BenchClient, ClientError


@pytest.fixture
def certificate(tmp_path):
    if shutil.which("openssl") is None:
        pytest.skip("openssl is not installed")
    cert, key = tmp_path / "cert.pem", tmp_path / "key.pem"
    subprocess.run(["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "2",
                    "-subj", "/CN=localhost", "-addext",
                    "subjectAltName=IP:127.0.0.1,DNS:localhost",
                    "-keyout", str(key), "-out", str(cert)],
                   check=True, capture_output=True)
    return cert, key


def test_a_tls_server_is_reached_by_a_client_that_trusts_its_certificate(
        bench_file, start_server, certificate, monkeypatch):
    cert, key = certificate
    monkeypatch.delenv("SCATTERLAB_CA", raising=False)
    server = start_server(bench_file(), args=("--tls-cert", str(cert), "--tls-key", str(key)))
    assert server.url.startswith("https://")
    with BenchClient(server.url, ca=str(cert)) as c:
        assert c.status()["bench"] == "sim"
        events = c.events()
        hello = next(events)
        assert hello.type == "hello"
        c.take_control(600)  # announced to every client: a frame through the fan-out
        assert any(m.type == "control" and m.data["holder"] == "local" for m in events)
        events.close()
    with BenchClient(server.url) as c, pytest.raises(ClientError) as err:
        c.status()  # the system's CAs do not know this certificate
    assert err.value.status == 0 and "CERTIFICATE_VERIFY_FAILED" in str(err.value)
