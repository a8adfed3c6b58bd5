"""What a fit says about itself: implausible or poorly determined results (Ljung §16)."""

from __future__ import annotations

import warnings

import numpy as np


class IdentificationWarning(UserWarning):
    """A fit finished, but its result is physically implausible or poorly determined.

    The message names the likely cause (reversed encoder or motor leads, friction larger than the
    input, a parameter at its bound, an input that does not excite the model).
    """


def _issue(msgs):
    for m in msgs:
        warnings.warn(m, IdentificationWarning, stacklevel=3)


def _diagnose(par, cov, names, u_abs_max, at_bound=()):
    """Physically impossible or poorly determined results -> list of messages (Ljung §16)."""
    msgs = []
    if not par["K"] > 0:
        msgs.append(
            f"K = {par['K']:.4g} rad/(V s) <= 0: the angle falls when the voltage rises. The "
            f"encoder channels (A/B) or the motor leads are probably reversed, or u was logged "
            f"with the wrong sign: flip the sign of theta (or of u) and fit again"
        )
    if not par["tau"] > 0:
        msgs.append(
            f"tau = {par['tau']:.4g} s <= 0: no motor has a negative time constant; check "
            f"that theta is the angle (not the velocity) and that the encoder and motor "
            f"leads are not reversed"
        )
    if "friction" in names and par["friction"] > u_abs_max:
        msgs.append(
            f"friction f_c = {par['friction']:.4g} V is larger than the largest input "
            f"|u| = {u_abs_max:.4g} V: the motor could never have moved. The model does not "
            f"fit these data (u not in volts? a reversed encoder? an offset or dead zone "
            f"not modelled?)"
        )
    for nm in at_bound:
        if nm == "dead_zone_max":
            msgs.append(
                f"dead_zone = {par['dead_zone']:.4g} V ran to its upper bound, the largest input "
                f"|u| = {u_abs_max:.4g} V: a dead zone that swallows the whole input would stop the "
                f"motor for good, so K ({par['K']:.3g}) was blown up against it. The input cannot "
                f"separate K from the dead zone (too few levels, or an offset or friction absorbs "
                f"it): fit without dead_zone, or record several input levels"
            )
            continue
        what = {
            "tau": "tau ran to the edge of its search range",
            "tau_coast": f"the coasting rate 1/tau_coast (tau_coast = {par.get('tau_coast', 0.0):.3g} s) "
            f"is at (or within two standard errors of) its bound 0: the open motor "
            f"shows no viscous drag. With friction, fit coast='coulomb' instead",
            "friction": f"friction f_c = {par['friction']:.3g} V is at (or within two standard "
            f"errors of) its bound 0",
            "dead_zone": f"dead_zone = {par['dead_zone']:.3g} V is at (or within two standard "
            f"errors of) its bound 0",
        }[nm]
        msgs.append(
            f"{what}: the data do not support this term (or another term absorbed it); "
            f"fit without it or record an input that shows it"
        )
    std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    # (all zero is a noise-free record; some zero while others are not is a rank-deficient fit)
    bad = [
        names[i]
        for i in range(len(names))
        if names[i] not in at_bound
        and (not np.isfinite(std[i]) or (std[i] == 0 and np.nanmax(std) > 0))
    ]
    if bad:
        msgs.append(
            f"singular fit: the standard error of {', '.join(bad)} is zero or undefined, so "
            f"the data do not determine {'it' if len(bad) == 1 else 'them'} (a parameter at a "
            f"bound, or several parameters trading off without limit); the values are not "
            f"estimates: fit fewer parameters or record a richer input"
        )
    elif np.all(np.isfinite(cov)):
        C = cov / np.outer(std, std)
        w, V = np.linalg.eigh(C)
        if w[0] < 1e-4:
            v = V[:, 0]
            idx = np.argsort(-np.abs(v))[:2]
            pair = " and ".join(names[i] for i in idx)
            msgs.append(
                f"ill-conditioned fit (parameter correlation matrix eigenvalue {w[0]:.1e}): "
                f"the input is not exciting enough to separate {pair}. A single step level "
                f"cannot separate K from friction or offset, a motor turning one way cannot "
                f"separate friction from offset: use two or more levels, both directions "
                f"(a PRBS about zero), or fewer parameters"
            )
    for i, nm in enumerate(names):
        val = par[nm]
        if (
            nm in ("K", "tau", "tau_coast")
            and nm not in at_bound
            and np.isfinite(std[i])
            and val != 0
            and std[i] > 0.5 * abs(val)
        ):
            msgs.append(
                f"{nm} is poorly determined ({val:.4g} ± {std[i]:.2g}): the input is not "
                f"exciting enough (too short, too small, or too slow for tau)"
            )
    return msgs
