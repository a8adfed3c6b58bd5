"""A real JupyterHub of deploy/jupyterhub/jupyterhub_config.py on 127.0.0.1, for the hub tests.

Root only (the hub starts each student's server as their own Unix user): the students are real
Unix users made by deploy/jupyterhub/roster.py with ``useradd`` and removed with ``userdel``
afterwards. Not root: the tests skip (fail under ``JERKLAB_REQUIRE_TOOLS``).
"""

from __future__ import annotations

import contextlib
import csv
import http.cookiejar
import json
import os
import pathlib
import pwd
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.parse
import urllib.request
import uuid

import pytest
from conftest import REQUIRE_TOOLS, require_tool

ROOT = pathlib.Path(__file__).resolve().parent.parent
#: the config under test (``JERKLAB_TEST_HUB_CONFIG`` points elsewhere, e.g. an older one)
CONFIG = pathlib.Path(
    os.environ.get("JERKLAB_TEST_HUB_CONFIG")
    or ROOT / "deploy" / "jupyterhub" / "jupyterhub_config.py"
)
ROSTER_SCRIPT = ROOT / "deploy" / "jupyterhub" / "roster.py"
MARK = "jerklab student"
#: the class rig service's address the test hub hands its students' servers
CLASS_RIG = "classrig://127.0.0.1:7341"


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def api(url, token, method="GET", body=None, timeout=30):
    data = json.dumps(body).encode() if body is not None else (b"" if method == "POST" else None)
    req = urllib.request.Request(
        url,
        data=data,
        method=method,
        headers={"Authorization": f"token {token}", "Content-Type": "application/json"},
    )
    with urllib.request.urlopen(req, timeout=timeout) as r:
        txt = r.read().decode()
        return r.status, (json.loads(txt) if txt.strip().startswith(("{", "[")) else txt)


def need_root():
    pytest.importorskip("jupyterhub")
    pytest.importorskip("firstuseauthenticator")
    require_tool("configurable-http-proxy", "useradd", "userdel")
    if os.geteuid() != 0:
        msg = "needs root: the hub starts each student's server as their own Unix user"
        if REQUIRE_TOOLS:
            pytest.fail(msg)
        pytest.skip(msg)


def _remove_user(name):
    try:
        pw = pwd.getpwnam(name)
    except KeyError:
        return
    if pw.pw_gecos.split(",")[0] != MARK and not name.startswith("jlt-"):
        raise RuntimeError(f"{name} exists and is not a test account")
    subprocess.run(["pkill", "-KILL", "-u", name], capture_output=True)
    subprocess.run(["userdel", "--force", name], capture_output=True)
    subprocess.run(["groupdel", name], capture_output=True)


def _closed_dirs():
    """Folders on the way to this Python, its venv and the checkout that others cannot enter."""
    out = []
    for target in (pathlib.Path(sys.executable).resolve(), pathlib.Path(sys.prefix), ROOT):
        for d in [*reversed(target.parents), target]:
            if d.is_dir() and not d.stat().st_mode & 0o001 and d not in out:
                out.append(d)
    return out


def _grant(users):
    """Let ``users`` (only them) enter the folders of :func:`_closed_dirs` (an ACL, undone after).

    This machine's Python may live under ``/root`` (0700); on a class server it is installed
    where every user may run it (docs/INSTRUCTOR.md). Returns ``[(folder, had_an_acl)]``.
    """
    dirs = _closed_dirs()
    if dirs:
        require_tool("setfacl", "getfacl")
    out = []
    for d in dirs:
        had = subprocess.run(
            ["getfacl", "--skip-base", "--absolute-names", str(d)], capture_output=True, text=True
        ).stdout.strip()
        out.append((d, bool(had)))
        for u in users:
            subprocess.run(["setfacl", "-m", f"u:{u}:x", str(d)], check=True)
    return out


def _ungrant(granted, users):
    for d, had in granted:
        if had:
            for u in users:
                subprocess.run(["setfacl", "-x", f"u:{u}", str(d)], capture_output=True)
        else:  # back to the plain mode bits it had
            subprocess.run(["setfacl", "-b", str(d)], capture_output=True)


class Hub:
    """A running hub: ``base`` URL, ``token`` (admin service), ``passwords``, ``pid``, paths."""

    def login(self, username, password):
        """Log in through the hub's login form; returns (logged_in, opener with its cookies)."""
        jar = http.cookiejar.CookieJar()

        class NoRedirect(urllib.request.HTTPRedirectHandler):
            def redirect_request(self, *a, **k):
                return None

        opener = urllib.request.build_opener(urllib.request.HTTPCookieProcessor(jar), NoRedirect)
        opener.open(self.base + "/hub/login", timeout=30).read()
        xsrf = next((c.value for c in jar if c.name == "_xsrf"), "")
        body = urllib.parse.urlencode(
            {"username": username, "password": password, "_xsrf": xsrf}
        ).encode()
        try:
            with opener.open(
                urllib.request.Request(self.base + "/hub/login", data=body, method="POST"),
                timeout=30,
            ) as r:
                status = r.status
        except urllib.error.HTTPError as e:
            status = e.code
        logged_in = status in (301, 302, 303) and any(c.name == "jupyterhub-hub-login" for c in jar)
        opener.xsrf = xsrf
        return logged_in, opener

    def get(self, opener, path):
        try:
            with opener.open(self.base + path, timeout=30) as r:
                return r.status, r.read().decode("utf-8", "replace")
        except urllib.error.HTTPError as e:
            return e.code, e.read().decode("utf-8", "replace")

    def user_token(self, name):
        """An API token of ``name``'s own (the admin service may make one)."""
        try:
            api(f"{self.base}/hub/api/users/{name}", self.token)
        except urllib.error.HTTPError as e:  # a hub that makes users only at first login
            if e.code != 404:
                raise
            api(f"{self.base}/hub/api/users/{name}", self.token, "POST")
        _, tok = api(f"{self.base}/hub/api/users/{name}/tokens", self.token, "POST", {"note": "t"})
        return tok["token"]

    def start_server(self, name, token, wait=150):
        _, info = api(f"{self.base}/hub/api/users/{name}", self.token)
        if info["servers"].get("", {}).get("ready"):
            return
        status, _ = api(f"{self.base}/hub/api/users/{name}/server", token, "POST")
        assert status in (201, 202), status
        t0 = time.monotonic()
        while True:
            _, info = api(f"{self.base}/hub/api/users/{name}", self.token)
            if info["servers"].get("", {}).get("ready"):
                return
            assert time.monotonic() - t0 < wait, f"{name}'s server not ready: {info}"
            time.sleep(1.0)


@contextlib.contextmanager
def running_hub(students, admin="jlt-instructor", rig=False):
    """Make the Unix users and logins of ``students`` + ``admin``, start the hub, yield a Hub."""
    need_root()
    for name in students + [admin, "jlt-rig"]:
        _remove_user(name)
    base_dir = pathlib.Path(tempfile.mkdtemp(prefix="jerklab-hubtest-", dir="/tmp"))
    os.chmod(base_dir, 0o711)
    state, homes = base_dir / "state", base_dir / "home"
    homes.mkdir()
    os.chmod(homes, 0o711)
    roster = base_dir / "roster.txt"
    roster.write_text("# the class\n" + "\n".join(students) + "\n")
    proc = log = None
    granted = []
    everyone = students + [admin, "jlt-rig"]
    try:
        # the broker's user, with its home in the test's folder (else the config makes one)
        subprocess.run(
            [
                "useradd",
                "--system",
                "--create-home",
                "--home-dir",
                str(base_dir / "rig"),
                "--shell",
                "/usr/sbin/nologin",
                "--user-group",
                "jlt-rig",
            ],
            check=True,
        )
        subprocess.run(
            [
                sys.executable,
                str(ROSTER_SCRIPT),
                str(roster),
                "--state",
                str(state),
                "--homes",
                str(homes),
                "--admin",
                admin,
            ],
            check=True,
            capture_output=True,
            text=True,
            timeout=120,
        )
        granted = _grant(everyone)
        with open(state / "passwords.csv", newline="") as f:
            passwords = {r["user"]: r["password"] for r in csv.DictReader(f)}
        hub = Hub()
        hub.passwords, hub.state, hub.homes, hub.admin = passwords, state, homes, admin
        port, api_port, proxy = free_port(), free_port(), free_port()
        hub.token = secrets.token_hex(16)
        hub.broker_port = free_port()
        env = dict(
            os.environ,
            JERKLAB_HUB_URL=f"http://127.0.0.1:{port}",
            JERKLAB_HUB_API_URL=f"http://127.0.0.1:{api_port}",
            JERKLAB_HUB_PROXY_API=f"http://127.0.0.1:{proxy}",
            JERKLAB_HUB_STATE=str(state),
            JERKLAB_HUB_ROSTER=str(roster),
            JERKLAB_HUB_ADMIN=admin,
            JERKLAB_HUB_ADMIN_TOKEN=hub.token,
            JERKLAB_RIG_PORT="virtual" if rig else "",
            JERKLAB_HUB_BROKER_PORT=str(hub.broker_port),
            JERKLAB_HUB_BROKER_USER="jlt-rig",
            # the class rig service's address, which every student's server gets
            JERKLAB_HUB_CLASS_RIG=CLASS_RIG,
            # a secret in the hub's environment, which no student may read
            JERKLAB_TEST_HUB_SECRET="hub-secret-" + uuid.uuid4().hex,
            PATH=os.path.dirname(sys.executable) + os.pathsep + os.environ["PATH"],
        )
        hub.secret = env["JERKLAB_TEST_HUB_SECRET"]
        log_path = base_dir / "hub.log"
        hub.log_path = log_path
        log = open(log_path, "w")
        proc = subprocess.Popen(
            [sys.executable, "-m", "jupyterhub", "-f", str(CONFIG)],
            cwd=base_dir,
            env=env,
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        hub.pid = proc.pid
        hub.base = f"http://127.0.0.1:{port}"
        t0 = time.monotonic()
        while True:
            try:
                api(hub.base + "/hub/api/", hub.token)
                break
            except (OSError, urllib.error.URLError):
                if proc.poll() is not None or time.monotonic() - t0 > 90:
                    lines = [  # the hub's own lines, not the proxy's retries
                        ln
                        for ln in log_path.read_text().splitlines()
                        if "ConfigProxy" not in ln and not ln.startswith((" ", "}"))
                    ]
                    pytest.fail("hub did not start:\n" + "\n".join(lines[-40:]))
                time.sleep(0.5)
        yield hub
    finally:
        if proc is not None:
            try:
                os.killpg(proc.pid, signal.SIGTERM)
                proc.wait(30)
            except Exception:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(proc.pid, signal.SIGKILL)
        if log is not None:
            log.close()
        _ungrant(granted, everyone)
        for name in everyone:
            _remove_user(name)
        shutil.rmtree(base_dir, ignore_errors=True)


def run_cell(base, user, token, code, timeout=180):
    """Start a kernel on the user's server, execute ``code``, return its stdout.

    Speaks the kernel websocket's v1 protocol, as JupyterLab does (the hub's servers refuse
    any other: jerklab._voila_guard). The cell is sent once, after a ``kernel_info`` reply has
    come back over the same websocket: a request sent while a new kernel (a new Unix user's,
    cold caches, a loaded machine) is still starting can be lost, and a cell must never run
    twice. ``timeout`` bounds the whole call, kernel start included.
    """
    import websocket  # websocket-client
    from jupyter_server.services.kernels.connection.base import (
        deserialize_msg_from_ws_v1,
        serialize_msg_to_ws_v1,
    )

    deadline = time.monotonic() + timeout
    session = uuid.uuid4().hex

    def send(ws, msg_type, content, channel="shell"):
        msg_id = uuid.uuid4().hex
        header = {
            "msg_id": msg_id,
            "username": user,
            "session": session,
            "msg_type": msg_type,
            "version": "5.3",
            "date": "",
        }
        parts = [json.dumps(x).encode() for x in (header, {}, {}, content)]
        ws.send_binary(serialize_msg_to_ws_v1(parts, channel))
        return msg_id

    def replies(ws):
        """(msg_type, parent msg_id, content) of each message, until the deadline."""
        while time.monotonic() < deadline:
            ws.settimeout(max(0.1, min(5.0, deadline - time.monotonic())))
            try:
                raw = ws.recv()
            except websocket.WebSocketTimeoutException:
                yield None, None, None
                continue
            _channel, msg_list = deserialize_msg_from_ws_v1(raw)
            head, parent, _meta, body = (json.loads(m) for m in msg_list[:4])
            yield head["msg_type"], parent.get("msg_id"), body
        raise AssertionError(f"{user}'s kernel: no reply in {timeout} s")

    _, kernel = api(f"{base}/user/{user}/api/kernels", token, "POST", {"name": "python3"})
    try:
        ws = websocket.create_connection(
            f"{base.replace('http', 'ws')}/user/{user}/api/kernels/{kernel['id']}/channels",
            header=[f"Authorization: token {token}"],
            subprotocols=["v1.kernel.websocket.jupyter.org"],
            timeout=min(60.0, timeout),
        )
        try:
            # the channel is live once a kernel_info request of ours is answered (resent each
            # 5 s of silence: kernel_info has no effect, so asking twice is harmless)
            asked = {send(ws, "kernel_info_request", {})}
            for kind, parent, _body in replies(ws):
                if kind == "kernel_info_reply" and parent in asked:
                    break
                if kind is None:
                    asked.add(send(ws, "kernel_info_request", {}))
            content = {
                "code": code,
                "silent": False,
                "store_history": False,
                "user_expressions": {},
                "allow_stdin": False,
            }
            msg_id = send(ws, "execute_request", content)
            out = []
            for kind, parent, body in replies(ws):
                if kind is None or parent != msg_id:
                    continue
                if kind == "stream":
                    out.append(body["text"])
                elif kind == "error":
                    raise AssertionError("\n".join(body["traceback"]))
                elif kind == "status" and body["execution_state"] == "idle":
                    return "".join(out)
        finally:
            ws.close()
    finally:
        try:  # a failure to clean up must not hide the test's own error
            api(f"{base}/user/{user}/api/kernels/{kernel['id']}", token, "DELETE")
        except (urllib.error.URLError, OSError) as exc:
            print(f"run_cell: could not delete {user}'s kernel: {exc}")
