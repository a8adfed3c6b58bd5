"""Create the class's accounts from a roster: one Unix user and one hub login per student.

Run as root on the hub's server, before starting the hub (and again when the roster grows)::

    sudo .venv/bin/python deploy/jupyterhub/roster.py roster.txt --state /srv/jerklab-hub

``roster.txt`` holds one user name a line (``#`` starts a comment). For every name this

* creates a Unix user with ``useradd`` (its own group, home ``<homes>/<name>`` with mode 0700,
  so no classmate reads it), marked ``jerklab student`` in its comment field;
* gives it a hub login of its own: a random password, stored as a bcrypt hash in
  FirstUseAuthenticator's password file ``<state>/passwords.dbm`` and written, with the name, to
  ``<state>/passwords.csv`` (mode 0600) for the instructor to hand out; the student changes it
  at ``/hub/auth/change-password``. Every name has its password before the hub starts, so no
  "first use" is left for a classmate to take.

The instructor (``--admin``, default ``instructor``) gets a login with a password of its own
(no class-wide password opens any account). ``<state>`` is made 0700 for root (the hub's user):
the database, cookie secret and passwords are out of every student's reach. A name that is
already a Unix account not made by this script (``root``, ``daemon``, a colleague) is refused,
as is a name that is not a plain Unix user name. A name already on the roster keeps its
password unless ``--reset NAME``.

deploy/jupyterhub/jupyterhub_config.py reads the same roster (``JERKLAB_HUB_ROSTER``) as the
hub's ``allowed_users``.
"""

from __future__ import annotations

import argparse
import csv
import os
import pathlib
import pwd
import re
import secrets
import subprocess
import sys

#: Comment field of the Unix users this script makes (and the only ones it will touch again).
MARK = "jerklab student"

#: A user name: lower-case letter first, then letters, digits, ``_`` or ``-``; at most 32.
NAME_RE = re.compile(r"^[a-z][a-z0-9_-]{0,31}$")


def read_roster(path):
    """The user names of a roster file, in order, validated; ValueError naming the line."""
    names = []
    text = pathlib.Path(path).read_text(encoding="utf-8")
    for i, raw in enumerate(text.splitlines(), 1):
        name = raw.split("#", 1)[0].strip()
        if not name:
            continue
        if not NAME_RE.match(name):
            raise ValueError(
                f"roster line {i}: {name!r} is not a user name (a-z first, then a-z 0-9 _ -, "
                "at most 32)"
            )
        if name in names:
            raise ValueError(f"roster line {i}: {name!r} is listed twice")
        names.append(name)
    if not names:
        raise ValueError(f"roster: {path} lists no user")
    return names


def _existing(name):
    try:
        return pwd.getpwnam(name)
    except KeyError:
        return None


def ensure_unix_user(name, homes, shell="/bin/bash"):
    """Create the Unix user ``name`` with a 0700 home under ``homes`` (or check the one there)."""
    home = pathlib.Path(homes) / name
    pw = _existing(name)
    if pw is None:
        subprocess.run(
            [
                "useradd",
                "--create-home",
                "--home-dir",
                str(home),
                "--shell",
                shell,
                "--user-group",
                "--comment",
                MARK,
                name,
            ],
            check=True,
        )
        pw = pwd.getpwnam(name)
    elif pw.pw_gecos.split(",")[0] != MARK:
        raise ValueError(
            f"{name!r} is already a Unix account not made for the class (comment "
            f"{pw.pw_gecos!r}); rename the student in the roster"
        )
    os.chmod(pw.pw_dir, 0o700)
    os.chown(pw.pw_dir, pw.pw_uid, pw.pw_gid)
    return pw


def _hash(password):
    import bcrypt

    return bcrypt.hashpw(password.encode("utf-8"), bcrypt.gensalt())


def set_logins(dbm_path, passwords):
    """Write ``{name: password}`` as bcrypt hashes into FirstUseAuthenticator's password file."""
    import dbm

    with dbm.open(str(dbm_path), "c", 0o600) as db:
        for name, password in passwords.items():
            db[name] = _hash(password)


def known_logins(dbm_path):
    """The names that already have a password in FirstUseAuthenticator's file."""
    import dbm

    try:
        with dbm.open(str(dbm_path), "r") as db:
            return {k.decode("utf-8") for k in db.keys()}
    except dbm.error:
        return set()


def main(argv=None):
    ap = argparse.ArgumentParser(prog="roster.py", description=__doc__.split("\n")[0])
    ap.add_argument("roster", help="file with one user name a line")
    ap.add_argument("--state", required=True, help="the hub's state folder (JERKLAB_HUB_STATE)")
    ap.add_argument("--homes", default="/home", help="parent folder of the homes (default /home)")
    ap.add_argument(
        "--admin", default="instructor", help="the instructor's login (default instructor)"
    )
    ap.add_argument("--reset", action="append", default=[], help="give NAME a new password")
    args = ap.parse_args(argv)
    if os.geteuid() != 0:
        ap.error("run as root: it creates Unix users (useradd)")
    names = read_roster(args.roster)
    if not NAME_RE.match(args.admin) or args.admin in names:
        ap.error(f"--admin {args.admin!r} must be a user name not on the roster")
    state = pathlib.Path(args.state)
    state.mkdir(parents=True, exist_ok=True)
    os.chown(state, 0, 0)
    os.chmod(state, 0o700)
    homes = pathlib.Path(args.homes)
    homes.mkdir(parents=True, exist_ok=True)
    for name in names + [args.admin]:
        ensure_unix_user(name, homes)
    dbm_path = state / "passwords.dbm"
    known = known_logins(dbm_path)
    new = {
        n: secrets.token_urlsafe(12)
        for n in names + [args.admin]
        if n not in known or n in args.reset
    }
    set_logins(dbm_path, new)
    out = state / "passwords.csv"
    rows = []
    if out.exists():
        with open(out, newline="", encoding="utf-8") as f:
            rows = [r for r in csv.reader(f) if r and r[0] not in new and r[0] != "user"]
    fd = os.open(out, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(["user", "password"])
        w.writerows(rows + sorted(new.items()))
    os.chmod(out, 0o600)
    print(f"{len(names)} students and {args.admin!r}: {len(new)} new password(s) in {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
