"""Classical Preisach hysteresis and its continuous numerical inversion (Xu & Meckl).

The piezo actuator of Xu & Meckl is a hysteresis operator ``H`` in front of linear
dynamics ``G`` (their Fig. 1).  ``H`` is modelled here by the classical Preisach
operator, discretized on a uniform grid of the Preisach half plane
``{(alpha, beta): u_min <= beta <= alpha <= u_max}``:

* the weight (Preisach density) ``mu`` is constant on each grid cell (diagonal cells
  are half squares), ``mu >= 0``;
* relay ``gamma_{alpha beta}`` switches to 1 when ``u >= alpha`` and to 0 when
  ``u <= beta`` (the {0, 1} relay convention: ``f = offset + integral of mu over
  S+``; the +-1 convention of Mayergoyz is the same operator with weight ``mu/2`` and
  another offset);
* the memory is the sequence of alternating dominant extrema (the staircase
  interface between ``S+`` and ``S-``), updated by the wiping-out rule;
* the output is computed from the Everett function
  ``E(alpha, beta) = integral of mu over {beta <= b <= a <= alpha}``, which for a
  piecewise-constant density is exact and piecewise quadratic, so every ascending
  or descending branch is continuous and monotone (Mayergoyz 1991, ch. 1).

The inversion is the CNIA of Xu & Meckl eq. 2: from the current memory,
find ``u*`` in ``[u_min, u_max]`` with ``|Gamma(u*; psi) - f_d| <= eps`` by bisection
on the monotone branch that leaves the current input (ascending if ``f_d`` is above
the current output, descending otherwise), ``eps`` = 0.2 % of the input range by
default (the value used for their Fig. 2).

Examples
--------
>>> P = Preisach.uniform(0.0, 100.0, n=50)
>>> y = P.apply([0.0, 60.0, 30.0, 80.0])
>>> u = P.invert(40.0)                        # commits u to the memory
>>> abs(P.output - 40.0) <= P.default_eps
True
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.optimize import nnls

from jerklab import paper as _paper
from jerklab._validate import as_finite_array, as_int, as_nonnegative, as_positive, as_real

__all__ = [
    "Preisach",
    "ForcData",
    "forc_experiment",
    "fit_preisach",
    "MAX_GRID",
    "MAX_FIT_GRID",
    "MAX_FORC_POINTS",
]

#: largest Preisach grid (n x n cells; the operator keeps three n x n tables as Python lists)
MAX_GRID = 1000
#: largest grid :func:`fit_preisach` fits (n (n + 1) / 2 weights by bounded least squares)
MAX_FIT_GRID = 100
#: most FORC points :func:`forc_experiment` measures (n_curves * points_per_curve)
MAX_FORC_POINTS = 1_000_000


def _check_grid(name, n):
    if n > MAX_GRID:
        raise ValueError(f"{name} = {n} exceeds MAX_GRID = {MAX_GRID} cells per side")
    return n


def _span(u_min, u_max) -> float:
    """``u_max - u_min``, a finite number > 0 (``ValueError`` naming both otherwise).

    Legal extremes: any finite pair whose difference is finite, e.g. ``(-1e307, 1e307)``.
    """
    span = u_max - u_min
    if not span > 0:
        raise ValueError(f"u_max must be > u_min, got u_min={u_min!r}, u_max={u_max!r}")
    if span == math.inf:
        raise ValueError(
            f"u_max - u_min overflows (u_min={u_min!r}, u_max={u_max!r}): scale the units"
        )
    return span


class Preisach:
    """Discretized classical Preisach operator with memory (Xu & Meckl, Fig. 1 ``H``).

    Parameters
    ----------
    u_min, u_max : float
        Input range.  Inputs outside it saturate (are clipped): every relay has
        switched already.  Any finite range is legal as long as the output swing
        (density times the cell area ``((u_max - u_min) / n)^2``) stays finite; a range of
        1e300 raises ``ValueError`` naming ``u_max - u_min``.
    density : array_like, shape (n, n)
        Preisach weight ``mu`` on the grid cells, ``density[i, j]`` for the cell with
        ``alpha`` in cell ``i`` and ``beta`` in cell ``j``; only the lower triangle
        ``i >= j`` is used.  Must be finite and ``>= 0`` (a negative weight would make
        branches non-monotone, and the CNIA would lose its guarantee).
    offset : float
        Output at negative saturation (every relay off).
    initial : {"negative", "positive"}
        Starting memory (negative or positive saturation), also used by :meth:`reset`.

    Notes
    -----
    Output of the operator (Mayergoyz): with the alternating extrema
    ``s_0 = u_min < s_1 > s_2 < ...`` (``s_last`` the current input),
    ``f = offset + sum_{i odd} E(s_i, s_{i-1}) - sum_{i even >= 2} E(s_{i-1}, s_i)``.
    """

    def __init__(self, u_min, u_max, density, offset=0.0, initial="negative"):
        self.u_min = as_real("u_min", u_min)
        self.u_max = as_real("u_max", u_max)
        _span(self.u_min, self.u_max)
        shape = np.shape(density) if isinstance(density, np.ndarray) else None
        if shape is not None and len(shape) == 2:
            _check_grid("density size", max(shape))
        mu = as_finite_array("density", density, ndim=2)
        _check_grid("density size", max(mu.shape))
        if mu.shape[0] != mu.shape[1] or mu.shape[0] < 1:
            raise ValueError(f"density must be a square (n, n) array, got shape {mu.shape}")
        mu = np.tril(mu)
        if np.any(mu < 0):
            raise ValueError("density must be >= 0 everywhere on alpha >= beta")
        self.offset = as_real("offset", offset)
        if initial not in ("negative", "positive"):
            raise ValueError(f"initial must be 'negative' or 'positive', got {initial!r}")
        self.initial = initial
        self.n = mu.shape[0]
        self.h = (self.u_max - self.u_min) / self.n
        self.density = mu
        M = mu + mu.T - np.diag(np.diag(mu))  # symmetric: E = L^T M L / 2
        self._M = M
        S = np.zeros((self.n + 1, self.n + 1))
        S[1:, 1:] = np.cumsum(np.cumsum(M, axis=0), axis=1)
        self._S = S  # 2-D prefix sums of M
        swing = self.h * self.h * S[-1, -1]  # twice the output swing of the major loop
        if not (self.h * self.h < math.inf and swing < math.inf):
            raise ValueError(
                f"u_max - u_min = {self.u_max - self.u_min!r} with this density gives an output "
                f"swing that overflows (cell area h^2 = {self.h * self.h!r}): scale the units"
            )
        R = np.zeros((self.n, self.n + 1))
        R[:, 1:] = np.cumsum(M, axis=1)
        self._R = R  # row prefix sums of M
        self._Ml = M.tolist()
        self._Sl = S.tolist()
        self._Rl = R.tolist()
        self.reset()

    # ------------------------------------------------------------------ constructors
    @classmethod
    def uniform(cls, u_min, u_max, n=50, gain=1.0, offset=None, initial="negative"):
        """Uniform Preisach density: major loop of parabolas, output span ``gain*(u_max-u_min)``.

        ``offset`` defaults to ``u_min`` so that, with ``gain = 1``, the output spans the
        input range (output in input units, as Xu & Meckl Fig. 2 plots ``u_c`` against ``u_r``).
        """
        u_min = as_real("u_min", u_min)
        u_max = as_real("u_max", u_max)
        n = _check_grid("n", as_int("n", n, minimum=1))
        gain = as_positive("gain", gain)
        span = _span(u_min, u_max)
        weight = 2.0 * gain / span
        if not (0.0 < weight < math.inf and gain * span < math.inf):
            raise ValueError(
                f"gain: the output span gain * (u_max - u_min) = {gain!r} * {span!r} is not a "
                f"finite number > 0 with a finite density 2 gain / span; scale the units"
            )
        mu = np.full((n, n), weight)
        return cls(u_min, u_max, mu, offset=u_min if offset is None else offset, initial=initial)

    @classmethod
    def from_density(
        cls, u_min, u_max, density: Callable, n=50, offset=0.0, initial="negative", quad=4
    ):
        """Discretize a density ``mu(alpha, beta)`` (vectorized callable) by cell averages.

        Each cell's weight is the mean of ``density`` over a ``quad x quad`` midpoint
        grid inside the cell (its part with ``alpha >= beta`` for diagonal cells).
        """
        u_min = as_real("u_min", u_min)
        u_max = as_real("u_max", u_max)
        n = _check_grid("n", as_int("n", n, minimum=1))
        quad = as_int("quad", quad, minimum=1)
        if quad > 64:
            raise ValueError(f"quad must be <= 64, got {quad}")
        if not callable(density):
            raise ValueError("density must be a callable mu(alpha, beta)")
        h = _span(u_min, u_max) / n
        q = (np.arange(quad) + 0.5) / quad
        lo = u_min + h * np.arange(n)
        A = lo[:, None] + h * q[None, :]  # alpha samples per cell row
        a = A[:, None, :, None]
        b = A[None, :, None, :]
        aa, bb = np.broadcast_arrays(a, b)
        vals = np.asarray(density(aa, bb), dtype=float)
        keep = aa >= bb
        vals = np.where(keep, vals, 0.0)
        cnt = keep.sum(axis=(2, 3))
        with np.errstate(invalid="ignore", divide="ignore"):
            mu = np.where(cnt > 0, vals.sum(axis=(2, 3)) / np.maximum(cnt, 1), 0.0)
        return cls(u_min, u_max, np.tril(mu), offset=offset, initial=initial)

    @classmethod
    def from_everett(cls, u_min, u_max, everett: Callable, n=50, offset=0.0, initial="negative"):
        """Build the operator from an Everett function ``E(alpha, beta)`` (vectorized callable).

        The mass of each cell is the mixed difference of ``E`` on the grid nodes
        (Mayergoyz: ``mu = -d^2 E / (d alpha d beta)``); the model's Everett function
        then equals ``everett`` exactly on every grid node.
        """
        u_min = as_real("u_min", u_min)
        u_max = as_real("u_max", u_max)
        n = as_int("n", n, minimum=1)
        if not callable(everett):
            raise ValueError("everett must be a callable E(alpha, beta)")
        x = np.linspace(u_min, u_max, n + 1)
        h = x[1] - x[0]
        if h <= 0:
            raise ValueError(f"u_max must be > u_min, got u_min={u_min!r}, u_max={u_max!r}")
        AA, BB = np.meshgrid(x, x, indexing="ij")
        E = np.where(AA >= BB, np.asarray(everett(AA, np.minimum(BB, AA)), dtype=float), 0.0)
        mass = np.zeros((n, n))
        for i in range(n):
            for j in range(i):
                mass[i, j] = E[i + 1, j] - E[i, j] - E[i + 1, j + 1] + E[i, j + 1]
            mass[i, i] = E[i + 1, i]
        area = np.full((n, n), h * h)
        np.fill_diagonal(area, h * h / 2)
        mu = np.tril(mass / area)
        # round-off of the mixed differences may leave tiny negative weights: clear those;
        # a genuinely negative mixed difference is not a Preisach Everett function (rejected)
        tiny = 1e-9 * max(np.abs(mu).max(), 1e-300)
        mu[(mu < 0) & (mu > -tiny)] = 0.0
        if np.any(mu < 0):
            raise ValueError(
                "everett must have a non-negative mixed difference "
                "(E(a2,b1) - E(a1,b1) - E(a2,b2) + E(a1,b2) >= 0)"
            )
        return cls(u_min, u_max, np.tril(mu), offset=offset, initial=initial)

    @classmethod
    def piezo_like(
        cls, u_min=0.0, u_max=100.0, n=50, gain=1.0, width=0.3, offset=None, initial="negative"
    ):
        """A piezo-like loop: density ``exp(-(alpha-beta)^2 / (2 (width*span)^2))``.

        Weight concentrated near the diagonal gives a narrow, nearly linear loop with
        ~10-15 % hysteresis (the shape of PZT stacks); normalized so that the output
        spans ``gain*(u_max - u_min)``; ``offset`` defaults to ``u_min``.
        """
        width = as_positive("width", width)
        gain = as_positive("gain", gain)
        u_min = as_real("u_min", u_min)
        u_max = as_real("u_max", u_max)
        span = u_max - u_min
        sig = width * span
        P = cls.from_density(
            u_min,
            u_max,
            lambda a, b: np.exp(-0.5 * ((a - b) / sig) ** 2),
            n=n,
            offset=0.0,
            initial=initial,
        )
        total = P.everett(u_max, u_min)
        return cls(
            u_min,
            u_max,
            P.density * (gain * span / total),
            offset=u_min if offset is None else offset,
            initial=initial,
        )

    def copy(self) -> "Preisach":
        """An independent operator with the same weights and the same current memory."""
        P = Preisach(self.u_min, self.u_max, self.density, self.offset, self.initial)
        P._s = list(self._s)
        P._c = list(self._c)
        return P

    # ------------------------------------------------------------------ Everett function
    def _E(self, alpha: float, beta: float) -> float:
        """Everett function for scalars (exact for the cell-wise constant density)."""
        if alpha <= beta:
            return 0.0
        n, h, u0 = self.n, self.h, self.u_min
        ia = min(int((beta - u0) / h), n - 1)
        ib = min(int((alpha - u0) / h), n - 1)
        M = self._Ml
        if ia == ib:
            return 0.5 * M[ia][ia] * (alpha - beta) ** 2
        pa = u0 + (ia + 1) * h - beta  # part of beta's cell above beta
        pb = alpha - (u0 + ib * h)  # part of alpha's cell below alpha
        S, R = self._Sl, self._Rl
        a1 = ia + 1
        full = S[ib][ib] - S[a1][ib] - S[ib][a1] + S[a1][a1]
        ra = R[ia][ib] - R[ia][a1]
        rb = R[ib][ib] - R[ib][a1]
        return (
            0.5 * h * h * full
            + h * (pa * ra + pb * rb)
            + 0.5 * (pa * pa * M[ia][ia] + pb * pb * M[ib][ib])
            + pa * pb * M[ib][ia]
        )

    def everett(self, alpha, beta):
        """Everett function ``E(alpha, beta)`` (0 where ``alpha <= beta``); arrays broadcast.

        ``E`` is the output drop along the first-order reversal curve that leaves the
        ascending major branch at ``alpha`` and descends to ``beta``:
        ``E(alpha, beta) = f_alpha - f_{alpha beta}`` ({0, 1} relays).
        """
        a = np.clip(as_finite_array("alpha", alpha), self.u_min, self.u_max)
        b = np.clip(as_finite_array("beta", beta), self.u_min, self.u_max)
        a, b = np.broadcast_arrays(a, b)
        out = np.array([self._E(float(x), float(y)) for x, y in zip(a.ravel(), b.ravel())])
        return float(out[0]) if a.ndim == 0 else out.reshape(a.shape)

    def masked_density(self) -> np.ndarray:
        """The weight ``mu`` on the Preisach half plane, NaN off it (for an image of it).

        ``out[i, j]`` is the weight of the cell with ``alpha`` in cell ``i`` and ``beta`` in
        cell ``j`` where ``i >= j``, NaN where ``i < j`` (``alpha < beta``, no relay there), so
        ``imshow(P.masked_density(), origin="lower", extent=[u_min, u_max, u_min, u_max])``
        shows the triangle only, with ``beta`` on the horizontal and ``alpha`` on the vertical axis.
        """
        return np.where(np.tri(self.n, dtype=bool), self.density, np.nan)

    # ------------------------------------------------------------------ memory
    def reset(self, state=None) -> "Preisach":
        """Reset the memory to negative or positive saturation (default: ``initial``)."""
        state = self.initial if state is None else state
        if state == "negative":
            self._s = [self.u_min]
            self._c = [0.0]
        elif state == "positive":
            self._s = [self.u_min, self.u_max]
            self._c = [0.0, self._E(self.u_max, self.u_min)]
        else:
            raise ValueError(f"state must be 'negative' or 'positive', got {state!r}")
        return self

    @property
    def state(self) -> tuple:
        """The memory: alternating extrema ``(u_min, M1, m1, M2, ..., u_current)``.

        ``u_min`` is the virtual minimum of negative saturation; the last entry is
        the current input.  Maxima decrease and minima increase along the sequence
        (wiping-out property).  Pass it to :meth:`set_state` to restore it.
        """
        return tuple(self._s)

    def set_state(self, state) -> "Preisach":
        """Restore a memory returned by :attr:`state` (checked for alternation)."""
        s = [float(v) for v in as_finite_array("state", state, ndim=1)]
        if not s or s[0] != self.u_min:
            raise ValueError("state must start with u_min (negative saturation)")
        for i in range(1, len(s)):
            if not self.u_min <= s[i] <= self.u_max:
                raise ValueError(f"state[{i}] = {s[i]!r} outside [u_min, u_max]")
            if (s[i] > s[i - 1]) != (i % 2 == 1) or s[i] == s[i - 1]:
                raise ValueError("state must alternate: u_min < M1 > m1 < M2 > ...")
            if i >= 2 and not (
                (i % 2 == 1 and s[i] < s[i - 2]) or (i % 2 == 0 and s[i] > s[i - 2])
            ):
                raise ValueError(
                    "state violates the wiping-out property (maxima must decrease, minima increase)"
                )
        self._s = s
        self._c = [0.0]
        for i in range(1, len(s)):
            self._c.append(self._c[-1] + self._term(s, i))
        return self

    def interface(self):
        """The staircase boundary of ``S+`` in the Preisach plane, as ``(beta, alpha)`` arrays.

        Runs from ``(u_min, M1)`` through the corners ``(m1, M1), (m1, M2), ...`` to the
        diagonal at the current input; ``S+`` (relays on) lies between this line, the
        edge ``beta = u_min`` and the diagonal.  Negative saturation: the single point
        ``(u_min, u_min)``.
        """
        s = self._s
        if len(s) == 1:
            return np.array([s[0]]), np.array([s[0]])
        b, a = [s[0]], [s[1]]
        for i in range(1, len(s) - 1):
            if i % 2 == 1:  # after a maximum: horizontal move in beta
                b.append(s[i + 1])
                a.append(s[i])
            else:  # after a minimum: vertical move in alpha
                b.append(s[i])
                a.append(s[i + 1])
        b.append(s[-1])
        a.append(s[-1])
        return np.array(b), np.array(a)

    def _term(self, s, i):
        return self._E(s[i], s[i - 1]) if i % 2 == 1 else -self._E(s[i - 1], s[i])

    def _new_stack(self, u):
        """Memory after moving the input to ``u`` (not committed): (stack, kept prefix length)."""
        s = self._s
        k = len(s)  # s[:k] kept unchanged
        cur = s[-1]
        if u == cur:
            return s, k
        up = u > cur
        if k >= 2 and (s[-1] > s[-2]) == up:
            k -= 1  # same direction: the current input is not an extremum
        # now s[k-1] is the last turning point kept; u continues from it
        while k >= 3 and ((up and u >= s[k - 2]) or (not up and u <= s[k - 2])):
            k -= 2  # wiping-out: u passes the previous extremum of its kind
        if not up and k == 2 and u <= s[0]:
            return [s[0]], 1  # back to negative saturation
        return s[:k] + [u], k

    def _eval(self, u):
        """Output for candidate input ``u`` from the current memory, without committing."""
        new, k = self._new_stack(u)
        if len(new) == 1:
            return self.offset
        i = len(new) - 1
        base = self._c[i - 1] if i - 1 < k else None
        if base is None:  # cannot happen: new[:i] == s[:i] with i <= k
            raise RuntimeError("memory bookkeeping error")
        return self.offset + base + self._term(new, i)

    def _commit(self, u):
        new, k = self._new_stack(u)
        if new is self._s:
            return
        c = self._c[: max(len(new) - 1, 1)]
        if len(new) > 1:
            c.append(c[-1] + self._term(new, len(new) - 1))
        self._s = list(new)
        self._c = c

    def _clip(self, u):
        return min(max(u, self.u_min), self.u_max)

    @property
    def output(self) -> float:
        """The current output ``Gamma(u_current; psi)``."""
        return self.offset + self._c[-1]

    @property
    def input(self) -> float:
        """The current input (last value applied, after saturation)."""
        return self._s[-1]

    @property
    def output_range(self) -> tuple:
        """(output at negative saturation, output at positive saturation)."""
        return (self.offset, self.offset + self._E(self.u_max, self.u_min))

    @property
    def default_eps(self) -> float:
        """0.2 % of the input range: the CNIA tolerance of Xu & Meckl (Fig. 2)."""
        return _paper.CNIA_EPS_FRACTION * (self.u_max - self.u_min)

    # ------------------------------------------------------------------ operator
    def peek(self, u):
        """Output for input ``u`` from the current memory, **without** changing the memory.

        Scalar ``u`` gives a float; an array gives each candidate's output from the
        same (current) memory — one point each on the two branches leaving it.
        """
        a = np.clip(as_finite_array("u", u), self.u_min, self.u_max)
        out = np.array([self._eval(float(v)) for v in a.ravel()])
        return float(out[0]) if a.ndim == 0 else out.reshape(a.shape)

    def apply(self, u):
        """Drive the operator with the input sequence ``u`` (memory kept in :attr:`state`).

        Returns the output after each sample (float for a scalar input).  The input
        is treated as piecewise monotone between samples (the Preisach operator is
        rate independent, so only the sequence of values matters).
        """
        a = as_finite_array("u", u)
        out = np.empty(a.size)
        for idx, v in enumerate(a.ravel()):
            self._commit(self._clip(float(v)))
            out[idx] = self.output
        return float(out[0]) if a.ndim == 0 else out.reshape(a.shape)

    __call__ = apply

    # ------------------------------------------------------------------ CNIA
    def invert(self, f_d, eps=None, commit=True, max_iter=200):
        """CNIA (Xu & Meckl eq. 2): ``u*`` with ``|Gamma(u*; psi) - f_d| <= eps``.

        From the current memory ``psi`` the output is continuous and non-decreasing in
        the next input (the ascending branch above the current input, the descending
        one below it), so bisection on that branch converges.  Targets outside the
        reachable range ``[Gamma(u_min; psi), Gamma(u_max; psi)]`` give the bound
        (``u_min`` or ``u_max``): the input never leaves ``[u_min, u_max]``.

        Parameters
        ----------
        f_d : float or array_like
            Desired output(s).  An array is inverted sample by sample, each ``u*``
            committed before the next (the history of a real input sequence).
        eps : float, optional
            Output tolerance; default :attr:`default_eps` (0.2 % of the input range).
        commit : bool
            Apply ``u*`` to the memory (default).  ``False`` leaves the memory
            unchanged (only for scalar ``f_d``).
        max_iter : int
            Bisection limit (the interval halves each time, so 200 is never reached
            for a tolerance above round-off).

        Returns
        -------
        float or ndarray
            ``u*`` in ``[u_min, u_max]``.
        """
        eps = self.default_eps if eps is None else as_positive("eps", eps)
        max_iter = as_int("max_iter", max_iter, minimum=1)
        fd = as_finite_array("f_d", f_d)
        if fd.ndim == 0:
            u = self._invert1(float(fd), eps, max_iter)
            if commit:
                self._commit(u)
            return u
        if not commit:
            raise ValueError("commit=False needs a scalar f_d (an array defines a history)")
        out = np.empty(fd.size)
        for idx, v in enumerate(fd.ravel()):
            u = self._invert1(float(v), eps, max_iter)
            self._commit(u)
            out[idx] = u
        return out.reshape(fd.shape)

    def _invert1(self, fd, eps, max_iter):
        cur = self._s[-1]
        f_cur = self.output
        if abs(f_cur - fd) <= eps:
            return cur
        if fd > f_cur:  # ascending branch from the current input
            lo, hi = cur, self.u_max
            f_hi = self._eval(hi)
            if f_hi <= fd + eps:
                return hi
        else:  # descending branch
            lo, hi = self.u_min, cur
            f_lo = self._eval(lo)
            if f_lo >= fd - eps:
                return lo
        best, best_err = cur, abs(f_cur - fd)
        for _ in range(max_iter):
            mid = 0.5 * (lo + hi)
            f = self._eval(mid)
            err = abs(f - fd)
            if err < best_err:
                best, best_err = mid, err
            if err <= eps or mid in (lo, hi):
                break
            if f < fd:
                lo = mid
            else:
                hi = mid
        return best


# ---------------------------------------------------------------------- FORC data and fit
@dataclass
class ForcData:
    """First-order reversal curves: output ``f`` after rising from negative saturation
    to ``alpha`` and descending to ``beta`` (``beta <= alpha``); ``beta == alpha`` gives
    the ascending major branch ``f_alpha``."""

    alpha: np.ndarray
    beta: np.ndarray
    f: np.ndarray
    u_min: float
    u_max: float


def forc_experiment(system, u_min, u_max, n_curves=20, points_per_curve=20) -> ForcData:
    """Measure FORCs on ``system`` (a :class:`Preisach` or any object with ``reset()``
    and ``apply(u)``): negative saturation, rise to each ``alpha``, descend in steps."""
    u_min = as_real("u_min", u_min)
    u_max = as_real("u_max", u_max)
    if not u_max > u_min:
        raise ValueError("u_max must be > u_min")
    n_curves = as_int("n_curves", n_curves, minimum=1)
    points_per_curve = as_int("points_per_curve", points_per_curve, minimum=1)
    if n_curves * points_per_curve > MAX_FORC_POINTS:
        raise ValueError(
            f"n_curves * points_per_curve = {n_curves * points_per_curve} exceeds "
            f"MAX_FORC_POINTS = {MAX_FORC_POINTS}"
        )
    if not (hasattr(system, "reset") and hasattr(system, "apply")):
        raise ValueError("system must have reset() and apply(u)")
    A, B, F = [], [], []
    for alpha in np.linspace(u_min, u_max, n_curves + 1)[1:]:
        system.reset()
        system.apply([u_min])
        fa = float(np.atleast_1d(system.apply([alpha]))[-1])
        A.append(alpha)
        B.append(alpha)
        F.append(fa)
        betas = np.linspace(alpha, u_min, points_per_curve + 1)[1:]
        ys = np.atleast_1d(system.apply(betas))
        A.extend([alpha] * len(betas))
        B.extend(betas)
        F.extend(ys)
    return ForcData(np.array(A), np.array(B), np.array(F), u_min, u_max)


def _cell_overlaps(a, b, u_min, h, n):
    """L[k, i] = length of [x_i, x_{i+1}] inside [b_k, a_k]."""
    x = u_min + h * np.arange(n + 1)
    lo = np.maximum(x[None, :-1], b[:, None])
    hi = np.minimum(x[None, 1:], a[:, None])
    return np.clip(hi - lo, 0.0, None)


def fit_preisach(forc_data: ForcData, n=20, regularization=0.0) -> Preisach:
    """Fit a discretized Preisach operator to first-order reversal data.

    Model (linear in the cell weights ``mu_ij >= 0`` and the offset):
    ``f_{alpha beta} = offset + E(alpha, u_min) - E(alpha, beta)``, with
    ``E(alpha, beta) = sum_{i>j} mu_ij L_i L_j + sum_i mu_ii L_i^2 / 2``, ``L_i`` the
    length of cell ``i`` inside ``[beta, alpha]``.  Solved as bounded least squares
    (``scipy.optimize.nnls``); ``regularization`` adds a ridge on the
    differences of neighbouring weights (smooth density from noisy data).
    """
    if not isinstance(forc_data, ForcData):
        raise ValueError("forc_data must be a ForcData (see forc_experiment)")
    n = as_int("n", n, minimum=1)
    if n > MAX_FIT_GRID:
        raise ValueError(f"n = {n} exceeds MAX_FIT_GRID = {MAX_FIT_GRID} (n (n + 1) / 2 unknowns)")
    lam = as_nonnegative("regularization", regularization)
    a = as_finite_array("forc_data.alpha", forc_data.alpha, ndim=1)
    b = as_finite_array("forc_data.beta", forc_data.beta, ndim=1)
    f = as_finite_array("forc_data.f", forc_data.f, ndim=1)
    if not (a.size == b.size == f.size) or a.size == 0:
        raise ValueError("forc_data.alpha, beta, f must have the same non-zero length")
    if np.any(b > a + 1e-12):
        raise ValueError("forc_data.beta must be <= alpha")
    u_min, u_max = float(forc_data.u_min), float(forc_data.u_max)
    h = (u_max - u_min) / n
    iu = np.tril_indices(n)

    def design(alpha, beta):
        L = _cell_overlaps(alpha, beta, u_min, h, n)
        Q = L[:, :, None] * L[:, None, :]
        Q[:, np.arange(n), np.arange(n)] *= 0.5
        return Q[:, iu[0], iu[1]]

    X = design(a, np.full_like(a, u_min)) - design(a, b)
    X = np.hstack([X, np.ones((a.size, 1))])
    y = f
    scale = np.abs(X[:, :-1]).max() or 1.0
    X[:, :-1] /= scale
    if lam > 0:
        m = len(iu[0])
        pos = {(i, j): k for k, (i, j) in enumerate(zip(*iu))}
        rows = []
        for (i, j), k in pos.items():
            for di, dj in ((1, 0), (0, 1)):
                nb = pos.get((i + di, j + dj))
                if nb is not None:
                    r = np.zeros(m + 1)
                    r[k], r[nb] = 1.0, -1.0
                    rows.append(r)
        if rows:
            D = np.array(rows) * math.sqrt(lam) * np.abs(y).max()
            X = np.vstack([X, D])
            y = np.concatenate([y, np.zeros(len(rows))])
    # non-negative least squares; the free offset is split as p - q with p, q >= 0
    X = np.hstack([X, -X[:, -1:]])
    x, _ = nnls(X, y, maxiter=50 * X.shape[1])
    mu = np.zeros((n, n))
    mu[iu] = x[:-2] / scale
    return Preisach(u_min, u_max, mu, offset=x[-2] - x[-1])
