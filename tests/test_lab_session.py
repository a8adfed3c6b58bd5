"""The lab session on the rig the grader serves into its sandbox (a pty): no wait after a run."""

from __future__ import annotations

import numpy as np
import pytest

from jerklab.lab.motors import practice_key, student_device, student_motor
from jerklab.lab.session import LabSession
from jerklab.rig.server import DeviceServer
from jerklab.rig.virtual import VirtualDevice


@pytest.fixture
def served(monkeypatch):
    """A student's motor served on a pty, as :func:`jerklab.lab.grade.grade_one` serves it."""
    motor = student_motor("pty001", practice_key())
    dev = student_device(motor)
    srv = DeviceServer(
        VirtualDevice(motor, count_noise=dev.count_noise, noise_seed=dev.noise_seed), speed=None
    )
    port = srv.start_pty()
    monkeypatch.setenv("JERKLAB_LAB_RIG_CPR", str(motor.encoder_ppr * motor.decoding))
    yield port, motor
    srv.close()


def test_steps_on_the_graders_rig_skip_wait_still_and_start_from_rest(
    served, monkeypatch, tmp_path
):
    port, motor = served
    monkeypatch.setenv("JERKLAB_LAB_RIG", port)
    S = LabSession(1, student="pty001", folder=tmp_path)
    try:
        assert S.rig.port == port and S.rig.instant_coast
        waits = []
        monkeypatch.setattr(S.rig, "wait_still", lambda *a, **k: waits.append(a) or True)
        S.step(9.0, 0.3, rest=0.05)
        rec = S.step(-6.0, 0.3, rest=0.05)
        assert waits == []
        # the served device coasted to rest at the end of the first run: the second step's
        # rest samples hold still but for the encoder's count noise
        n_rest = round(0.05 / rec.Ts)
        counts = rec.position[:n_rest] * motor.counts_per_rad
        assert np.ptp(counts) <= 1 + 8 * getattr(motor, "noise_counts", 0.0)
        # and it moved: -6 V drives it the negative way by many counts
        assert (rec.position[-1] - rec.position[n_rest]) * motor.counts_per_rad < -100
    finally:
        S.close()


def test_another_pty_rig_still_waits_until_the_motor_is_still(served, monkeypatch, tmp_path):
    port, _ = served
    monkeypatch.delenv("JERKLAB_LAB_RIG", raising=False)
    S = LabSession(1, student="pty001", port=port, folder=tmp_path)
    try:
        assert not S.rig.instant_coast
        waits = []
        monkeypatch.setattr(S.rig, "wait_still", lambda *a, **k: waits.append(a) or True)
        S.step(6.0, 0.2)
        assert len(waits) == 1
    finally:
        S.close()
