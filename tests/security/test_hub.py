"""Attacks on the class hub (issue 32, "Hub"), run as a student would run them: through the hub's
login form on 127.0.0.1, and as code in the student's own kernel.

The hub is deploy/jupyterhub/jupyterhub_config.py, with two real Unix users made by
deploy/jupyterhub/roster.py (useradd; root only, see tests/_hub.py) and the class page's broker
as a hub service. With the config before the fix (dummy authenticator, every server as the
hub's user) each of these passed: alice logged in as bob and as the instructor, and her kernel
read bob's files, the hub's environment, cookie secret and database.
"""

from __future__ import annotations

import json
import urllib.error

import pytest
from _hub import api, run_cell, running_hub

pytestmark = pytest.mark.slow

ALICE, BOB, ADMIN = "jlt-alice", "jlt-bob", "jlt-instructor"


@pytest.fixture(scope="module")
def hub():
    with running_hub([ALICE, BOB], admin=ADMIN, rig=True) as h:
        # a file of bob's, in his home as useradd made it
        import os
        import pwd

        pw = pwd.getpwnam(BOB)
        secret = os.path.join(pw.pw_dir, "secret.txt")
        with open(secret, "w") as f:
            f.write("bob's answers\n")
        os.chown(secret, pw.pw_uid, pw.pw_gid)
        os.chmod(secret, 0o644)  # even a readable file: his home (0700) keeps it his
        h.tokens = {u: h.user_token(u) for u in (ALICE, BOB)}
        yield h


def test_a_student_logs_in_as_nobody_else(hub):
    pw = hub.passwords
    assert hub.login(ALICE, pw[ALICE])[0]  # her own login works
    assert hub.login(ADMIN, pw[ADMIN])[0]  # the instructor's own credential works
    for who, password in [
        (BOB, pw[ALICE]),  # a classmate's name with her own password
        (ADMIN, pw[ALICE]),  # the instructor's name with hers
        (BOB, ""),
        (BOB, "class-secret"),  # the old shared class password
        ("jlt-carol", pw[ALICE]),  # a name not on the roster
        ("root", pw[ALICE]),
    ]:
        ok, _ = hub.login(who, password)
        assert not ok, f"logged in as {who!r} with a password that is not theirs"


def test_a_student_cannot_open_the_admin_page(hub):
    ok, alice = hub.login(ALICE, hub.passwords[ALICE])
    assert ok
    status, _ = hub.get(alice, "/hub/admin")
    assert status == 403, status
    with pytest.raises(urllib.error.HTTPError) as err:  # nor the admin API with her token
        api(f"{hub.base}/hub/api/users", hub.tokens[ALICE])
    assert err.value.code == 403
    ok, admin = hub.login(ADMIN, hub.passwords[ADMIN])
    assert ok and hub.get(admin, "/hub/admin")[0] == 200


ATTACK = """\
import glob, json, os
res = {}
def attempt(key, f):
    try:
        f()
        res[key] = "READ"
    except PermissionError:
        res[key] = "refused"
    except FileNotFoundError:
        res[key] = "missing"
bob = os.path.join(os.getcwd(), "..", BOB)
attempt("bob_home", lambda: os.listdir(bob))
attempt("bob_file", lambda: open(os.path.join(bob, "secret.txt")).read())
attempt("hub_environ", lambda: open(f"/proc/{HUB_PID}/environ", "rb").read())
attempt("cookie_secret", lambda: open(STATE + "/jupyterhub_cookie_secret", "rb").read())
attempt("database", lambda: open(STATE + "/jupyterhub.sqlite", "rb").read())
attempt("passwords", lambda: open(STATE + "/passwords.csv", "rb").read())
leaks = []
for p in glob.glob("/proc/[0-9]*/environ"):
    try:
        if SECRET.encode() in open(p, "rb").read():
            leaks.append(p)
    except OSError:
        pass
res["environ_leaks"] = len(leaks) + (SECRET in str(os.environ))
res["uid"] = os.getuid()
print("RES" + json.dumps(res))
"""


def test_a_students_kernel_reads_neither_classmates_nor_the_hub(hub):
    hub.start_server(ALICE, hub.tokens[ALICE])
    code = (
        f"BOB = {BOB!r}; HUB_PID = {hub.pid}; STATE = {str(hub.state)!r}; "
        f"SECRET = {hub.secret!r}\n" + ATTACK
    )
    out = run_cell(hub.base, ALICE, hub.tokens[ALICE], code)
    res = json.loads(out.split("RES", 1)[1])
    import pwd

    assert res["uid"] == pwd.getpwnam(ALICE).pw_uid != 0, res  # her kernel runs as her
    for key in ("bob_home", "bob_file", "hub_environ", "cookie_secret", "database", "passwords"):
        assert res[key] == "refused", (key, res)
    assert res["environ_leaks"] == 0, res


RIG_ATTACK = """\
import json, os
from jerklab import tuning
from jerklab.broker import BrokerError, BrokerRig
addr = os.environ["JERKLAB_RIG_PORT"]
rig = BrokerRig(addr, client=BOB)  # she types bob's name
rec = rig.run_move(tuning.move_profile(), tuning.compute_pole_placement().gains, path=False)
out = {"identity": rig.identity, "verified": rig.verified,
       "student": rec.metadata["student"], "kind": rec.metadata["identity"]}
for forged in ("", "0" * 32, os.environ["JUPYTERHUB_API_TOKEN"][::-1]):
    try:
        BrokerRig(addr, token=forged)
        out.setdefault("forged_ok", []).append(forged)
    except BrokerError as e:
        out.setdefault("forged_refused", []).append(str(e)[:80])
print("RES" + json.dumps(out))
"""


def test_the_rig_names_a_run_by_the_hub_login_not_a_typed_id(hub):
    hub.start_server(ALICE, hub.tokens[ALICE])
    try:
        out = run_cell(hub.base, ALICE, hub.tokens[ALICE], f"BOB = {BOB!r}\n" + RIG_ATTACK)
    except Exception:
        print("".join(hub.log_path.read_text(errors="replace").splitlines(True)[-150:]))
        raise
    res = json.loads(out.split("RES", 1)[1])
    assert res["identity"] == ALICE and res["verified"] is True, res
    assert res["student"] == ALICE and res["kind"] == "hub", res
    assert "forged_ok" not in res and len(res["forged_refused"]) == 3, res
    # the broker's own copy is alice's, none is bob's
    import pwd

    kept = pwd.getpwnam("jlt-rig").pw_dir + "/recordings"
    import pathlib

    folders = sorted({p.parent.name for p in pathlib.Path(kept).rglob("*.csv")})
    assert folders == [ALICE], folders
    # and a request from outside any kernel, without a token, is refused
    from jerklab.broker import BrokerError, BrokerRig

    with pytest.raises(BrokerError, match="token"):
        BrokerRig(f"broker://127.0.0.1:{hub.broker_port}", token="")


def test_a_legacy_kernel_websocket_is_refused_on_a_students_server(hub):
    """Voila's hang (tests/security/test_queue.py) on the hub: her own server, with her own
    token, refuses a kernel websocket without the v1 subprotocol before it can spin."""
    import websocket

    hub.start_server(ALICE, hub.tokens[ALICE])
    token = hub.tokens[ALICE]
    _, kernel = api(f"{hub.base}/user/{ALICE}/api/kernels", token, "POST", {"name": "python3"})
    try:
        url = f"{hub.base.replace('http', 'ws')}/user/{ALICE}/api/kernels/{kernel['id']}/channels"
        with pytest.raises(websocket.WebSocketBadStatusException) as err:
            websocket.create_connection(url, header=[f"Authorization: token {token}"], timeout=30)
        assert err.value.status_code == 400
        # and the server answers
        status, _ = api(f"{hub.base}/user/{ALICE}/api/status", token, timeout=15)
        assert status == 200
    finally:
        api(f"{hub.base}/user/{ALICE}/api/kernels/{kernel['id']}", token, "DELETE")
