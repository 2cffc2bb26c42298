"""Issue 10: TLS and access control for the daemon's Zenoh session, set through `[zenoh]` and its
`options` pass-through table only (no imud code knows about either).

The certificates are made here with the `openssl` command (a CA, the daemon's certificate for
127.0.0.1, client certificates whose common names the access rules match, and a second CA nobody
trusts). Three daemons, each with simulated devices, in this process:

* TLS only (server authentication): a client that trusts the CA receives batches and status; a
  client without the CA, with the wrong CA, or speaking plain TCP to the TLS port cannot connect.
* configs/examples/zenoh-tls-acl.toml itself (its ports and certificate paths swapped for the
  test's): mutual TLS plus access control by certificate common name. The client whose
  certificate says CN=navigation gets imu0 and the status, and nothing of imu1 (nor of a
  subscription to `imud/**`, which is wider than its rule); a client with a valid certificate
  under another name gets nothing at all; a TLS client without a certificate, or with one that
  says CN=navigation but comes from another CA, cannot connect; a local tool on loopback TCP gets
  everything.
* user/password authentication (`transport/auth/usrpwd`) over plain TCP, with access control by
  user name: the allowed user gets imu0, another user gets nothing, a wrong password cannot
  connect.

"Gets nothing" is checked against a positive control in the same run: the denied subscriber was
declared before the allowed one, and is empty after the allowed one received 20 batches.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import time
import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import zenoh

import imud.client as ic
from imud.config import parse_config
from imud.daemon import Daemon
from tests.helpers import free_port, run_in_process

REPO = Path(__file__).resolve().parent.parent
EXAMPLE = REPO / "configs" / "examples" / "zenoh-tls-acl.toml"
DEADLINE_S = 20.0  # against hanging only; nothing asserts how long a step took
ALLOWED_BATCHES = 20

pytestmark = [
    pytest.mark.slow,  # TLS and ACL sessions through the daemon
    pytest.mark.skipif(shutil.which("openssl") is None, reason="needs the openssl CLI"),
]


# --- certificates ---------------------------------------------------------------------------------
def _openssl(*args: str, cwd: Path) -> None:
    subprocess.run(["openssl", *args], cwd=cwd, check=True, capture_output=True, timeout=30)


def _ca(d: Path, name: str) -> None:
    _openssl("req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256", "-nodes",
             "-keyout", f"{name}.key", "-out", f"{name}.pem", "-days", "2",
             "-subj", f"/CN={name}", cwd=d)  # fmt: skip


def _leaf(d: Path, name: str, cn: str, ca: str = "ca") -> None:
    """A certificate signed by `ca`, good for both ends of a TLS link. The subject alternative
    names are what a client checks against the address in its endpoint (tls/127.0.0.1:...)."""
    (d / f"{name}.ext").write_text(
        "subjectAltName=DNS:localhost,IP:127.0.0.1\nbasicConstraints=CA:FALSE\n"
        "keyUsage=digitalSignature\nextendedKeyUsage=serverAuth,clientAuth\n"
    )
    _openssl("req", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256", "-nodes",
             "-keyout", f"{name}.key", "-out", f"{name}.csr",
             "-subj", f"/CN={cn}", cwd=d)  # fmt: skip
    _openssl("x509", "-req", "-in", f"{name}.csr", "-CA", f"{ca}.pem", "-CAkey", f"{ca}.key",
             "-CAcreateserial", "-out", f"{name}.pem", "-days", "2",
             "-extfile", f"{name}.ext", cwd=d)  # fmt: skip


@pytest.fixture(scope="module")
def certs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("tls")
    _ca(d, "ca")
    _ca(d, "other-ca")  # valid, but trusted by nobody here
    _leaf(d, "imud", "imud")
    _leaf(d, "navigation", "navigation")
    _leaf(d, "intruder", "intruder")
    _leaf(d, "stranger", "navigation", ca="other-ca")  # the allowed name, from the wrong CA
    return d


# --- sessions -------------------------------------------------------------------------------------
def client(endpoint: str, transport: dict[str, Any] | None = None) -> zenoh.Session:
    """A client session to one endpoint, multicast off, with `transport` settings (TLS files,
    user/password). Retried while the daemon's listener is not open yet; raises `zenoh.ZError`
    when the far end is there but refuses the session."""
    conf: dict[str, Any] = {
        "mode": "client",
        "connect": {"endpoints": [endpoint]},
        "scouting": {"multicast": {"enabled": False}},
        "transport": {"shared_memory": {"enabled": False}, **(transport or {})},
    }
    return zenoh.open(zenoh.Config.from_json5(json.dumps(conf)))


def tls(certs: Path, ca: str | None = "ca", me: str | None = None) -> dict[str, Any]:
    t: dict[str, Any] = {}
    if ca is not None:
        t["root_ca_certificate"] = str(certs / f"{ca}.pem")
    if me is not None:
        t |= {
            "enable_mtls": True,
            "connect_certificate": str(certs / f"{me}.pem"),
            "connect_private_key": str(certs / f"{me}.key"),
        }
    return {"link": {"tls": t}}


def wait_listening(endpoint: str, transport: dict[str, Any]) -> zenoh.Session:
    """The first session the daemon accepts (it opens its listeners after this test starts)."""
    end = time.monotonic() + DEADLINE_S
    while True:
        try:
            return client(endpoint, transport)
        except zenoh.ZError:
            assert time.monotonic() < end, f"the daemon never accepted a session on {endpoint}"
            time.sleep(0.1)


def refused(endpoint: str, transport: dict[str, Any] | None = None) -> bool:
    try:
        s = client(endpoint, transport)
    except zenoh.ZError:
        return True
    s.close()  # type: ignore[no-untyped-call]
    return False


def sub(session: zenoh.Session, key: str) -> Any:
    return session.declare_subscriber(key, zenoh.handlers.FifoChannel(4096))


def take(subscriber: Any, n: int) -> list[ic.Batch]:
    """`n` batches from a subscriber that is allowed them."""
    got: list[ic.Batch] = []
    end = time.monotonic() + DEADLINE_S
    while len(got) < n:
        sample = subscriber.try_recv()
        if sample is None:
            assert time.monotonic() < end, f"only {len(got)} of {n} batches arrived"
            time.sleep(0.01)
            continue
        got.append(ic.decode(sample.payload.to_bytes()))
    return got


def drained(subscriber: Any) -> int:
    n = 0
    while subscriber.try_recv() is not None:
        n += 1
    return n


def devices_in(subscriber: Any) -> set[str]:
    """The devices of every batch that reached `subscriber` so far."""
    out: set[str] = set()
    while (sample := subscriber.try_recv()) is not None:
        out.add(ic.decode(sample.payload.to_bytes()).device)
    return out


def no_status(session: zenoh.Session) -> bool:
    try:
        ic.get_status(session, timeout=1.0)
    except ic.NoDaemon:
        return True
    return False


def sim_devices() -> list[dict[str, Any]]:
    return [
        {"name": name, "chip": "mpu6050", "odr_hz": 200,
         "bus": {"kind": "sim", "bus": "simS", "address": address}}
        for name, address in (("imu0", 0x68), ("imu1", 0x69))
    ]  # fmt: skip


def run_daemon(raw: dict[str, Any], drive: Callable[[], None]) -> None:
    """Run a daemon configured by `raw` while `drive()` talks to it; re-raise what `drive`
    raised."""
    daemon = Daemon(parse_config(raw))
    failure: list[BaseException] = []

    def wrapped() -> None:
        try:
            drive()
        except BaseException as e:  # reported below
            failure.append(e)
        finally:
            daemon.request_stop()

    run_in_process(daemon, wrapped)
    if failure:
        raise failure[0]


# --- TLS ------------------------------------------------------------------------------------------
def test_tls_client_with_the_ca_gets_data_others_cannot_connect(certs: Path) -> None:
    endpoint = f"tls/127.0.0.1:{free_port()}"
    opts = {
        "transport/link/tls/listen_certificate": str(certs / "imud.pem"),
        "transport/link/tls/listen_private_key": str(certs / "imud.key"),
    }
    raw = {"zenoh": {"listen": [endpoint], "options": opts}, "device": sim_devices()}

    def drive() -> None:
        with wait_listening(endpoint, tls(certs)) as s:
            assert take(sub(s, ic.data_key("imu0")), 3)[0].device == "imu0"
            assert {d["name"] for d in ic.get_status(s)["devices"]} == {"imu0", "imu1"}
        assert refused(endpoint, tls(certs, ca=None))  # cannot check the daemon's certificate
        assert refused(endpoint, tls(certs, ca="other-ca"))  # signed by a CA it does not trust
        assert refused(endpoint.replace("tls/", "tcp/"))  # plain TCP to the TLS port

    run_daemon(raw, drive)


# --- access control -------------------------------------------------------------------------------
def example_for_test(certs: Path) -> tuple[dict[str, Any], str, str]:
    """configs/examples/zenoh-tls-acl.toml with free loopback ports and the test's certificates
    in place of its placeholders; everything else as shipped."""
    raw = tomllib.loads(EXAMPLE.read_text())
    tcp, tls_ep = f"tcp/127.0.0.1:{free_port()}", f"tls/127.0.0.1:{free_port()}"
    assert raw["zenoh"]["listen"] == ["tcp/127.0.0.1:7450", "tls/127.0.0.1:7451"]
    raw["zenoh"]["listen"] = [tcp, tls_ep]
    opts = raw["zenoh"]["options"]
    files = {"ca.pem": "ca.pem", "imud.pem": "imud.pem", "imud.key": "imud.key"}
    for key, value in opts.items():
        if isinstance(value, str) and value.startswith("/etc/imud/tls/"):
            opts[key] = str(certs / files[value.removeprefix("/etc/imud/tls/")])
    assert sum(str(v).startswith(str(certs)) for v in opts.values()) == 3
    return raw, tcp, tls_ep


def test_example_config_lets_each_subject_see_only_its_keys(certs: Path) -> None:
    raw, tcp, tls_ep = example_for_test(certs)
    assert {d["name"] for d in raw["device"]} == {"imu0", "imu1"}

    def drive() -> None:
        with (
            wait_listening(tls_ep, tls(certs, me="intruder")) as intruder,
            client(tls_ep, tls(certs, me="navigation")) as nav,
            client(tls_ep, tls(certs, me="navigation")) as nav_wide,
            client(tcp) as local,
        ):
            # the denied subscriptions first: declared before the allowed ones below
            intruder_subs = [sub(intruder, k) for k in ("imud/imu0/imu", "imud/**")]
            nav_imu1 = sub(nav, "imud/imu1/imu")
            wide = sub(nav_wide, "imud/**")  # wider than the rule: refused, not narrowed
            shared = sub(nav, "imud/**")  # gets what the session's allowed imu0 subscription gets
            nav_imu0 = sub(nav, "imud/imu0/imu")
            local_imu1 = sub(local, "imud/imu1/imu")
            assert all(b.device == "imu0" for b in take(nav_imu0, ALLOWED_BATCHES))
            assert all(b.device == "imu1" for b in take(local_imu1, 3))  # local sees all
            assert drained(nav_imu1) == 0  # not navigation's device
            assert drained(wide) == 0
            assert devices_in(shared) == {"imu0"}
            assert [drained(s) for s in intruder_subs] == [0, 0]
            # status: navigation may ask the daemon's; the intruder gets no answer
            assert {d["name"] for d in ic.get_status(nav)["devices"]} == {"imu0", "imu1"}
            assert ic.get_status(nav, device="imu0")["name"] == "imu0"
            assert no_status(intruder)
            assert ic.get_status(local, device="imu1")["name"] == "imu1"
        # mutual TLS: the CA alone no longer gets a TLS client in
        assert refused(tls_ep, tls(certs))
        assert refused(tls_ep, tls(certs, me="stranger"))

    run_daemon(raw, drive)


def test_usrpwd_users_get_only_what_the_rules_allow(tmp_path: Path) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    users = tmp_path / "users.txt"
    users.write_text("navigation:nav-secret\nguest:guest-secret\n")  # user:password per line
    users.chmod(0o600)
    acl = {
        "enabled": True,
        "default_permission": "deny",
        "rules": [{"id": "imu0", "permission": "allow", "flows": ["ingress", "egress"],
                   "messages": ["declare_subscriber", "put"], "key_exprs": ["imud/imu0/**"]}],
        "subjects": [{"id": "nav", "usernames": ["navigation"]}],
        "policies": [{"rules": ["imu0"], "subjects": ["nav"]}],
    }  # fmt: skip
    opts = {"transport/auth/usrpwd/dictionary_file": str(users), "access_control": acl}
    raw = {"zenoh": {"listen": [endpoint], "options": opts}, "device": sim_devices()}

    def login(user: str, password: str) -> dict[str, Any]:
        return {"auth": {"usrpwd": {"user": user, "password": password}}}

    def drive() -> None:
        with (
            wait_listening(endpoint, login("guest", "guest-secret")) as guest,
            client(endpoint, login("navigation", "nav-secret")) as nav,
        ):
            guest_imu0 = sub(guest, "imud/imu0/imu")
            nav_imu1 = sub(nav, "imud/imu1/imu")
            nav_imu0 = sub(nav, "imud/imu0/imu")
            assert all(b.device == "imu0" for b in take(nav_imu0, ALLOWED_BATCHES))
            assert drained(guest_imu0) == 0
            assert drained(nav_imu1) == 0
        assert refused(endpoint, login("navigation", "wrong"))
        assert refused(endpoint)  # no credentials at all

    run_daemon(raw, drive)
