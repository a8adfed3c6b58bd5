"""``jerklab app --profile``: the class page's rig runs the rig's motor profile."""

from __future__ import annotations

import pytest

pytest.importorskip("ipywidgets")


def test_the_page_connects_with_the_profile(monkeypatch, tmp_path):
    from jerklab import app

    monkeypatch.setenv("JERKLAB_RECORDINGS", str(tmp_path))
    monkeypatch.setenv(app.PROFILE_ENV, "jgb37-520-30")
    p = app.panel_for_page(rig_port="virtual")
    try:
        assert p.rig.profile.name == "jgb37-520-30" and p.rig.counts_per_rev == 1320
        assert p.rig.model[0] == pytest.approx(p.rig.profile.K)
    finally:
        p.rig.close()


def test_the_option_is_checked_and_handed_to_the_kernels(monkeypatch):
    voila_app = pytest.importorskip("voila.app")
    from jerklab import app

    seen = {}
    monkeypatch.setattr(
        voila_app, "main", lambda argv: seen.setdefault("env", app.os.environ[app.PROFILE_ENV])
    )
    # set, then removed, so that monkeypatch restores the variable's absence after app.main sets
    # it (a delenv of an absent variable records nothing, and the profile leaked into the
    # worker's later tests: their virtual rig ran the 37D motor)
    monkeypatch.setenv(app.PROFILE_ENV, "")
    monkeypatch.delenv(app.PROFILE_ENV)
    with pytest.raises(SystemExit):
        app.main(["--profile", "no-such-motor"])
    app.main(["--profile", "pololu-37d-30", "--pool", "0"])
    assert seen["env"] == "pololu-37d-30"
