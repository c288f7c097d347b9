"""The navigation filter: an error-state Kalman filter on every control step (issue 14).

State: the process model's error states (:mod:`companion.nav.process`: 15 INS error states, or
4 dead-reckoning states) followed by one bias state per measured element (D, I in degrees;
F, H, Z in nT): what the measurement carries beyond the main-field model at the true position
(the heading's bias in D, the main-field model's and the crust's error, a magnetic storm, a
calibration residual), each a random walk; then, when configured, the local model-error states
(the part of the model's error that changes along the route, the crust: :mod:`companion.nav.local_error`):
per element a Gauss-Markov process in the *distance travelled* ``d = |v| dt``, first order
(``m' = exp(-d / L) m``, one state) or second order (FUS_GM_ORDER 2: smooth, the value and its
slope), its variance relaxing to ``sigma_local^2``, so standing still does not decorrelate it; then, when
configured, four heading states per element: the magnetometer's calibration residual, which sits
in the body frame and so changes the elements as the vehicle turns. To first order a hard-iron
offset ``o`` appears in the north-east-down field as ``R(psi) o`` and a soft-iron residual ``S``
as ``R(psi) S R(psi)^T B``: a constant (carried by the bias state) plus the first and second
harmonics of the true heading ``psi``, ``c^T [cos psi, sin psi, cos 2 psi, sin 2 psi]``, whose
coefficients ``c`` are constants with prior 1-sigma ``heading_deg`` / ``heading_nt``. Their
measurement columns are that row at the window's heading (:meth:`NavigationFilter.set_heading`);
with the heading unknown they are zero and the residual's variance at a random heading,
``2 sigma^2``, is added to R instead.

Measurement form: the averaged elements directly, as innovations against the field model with
its Jacobian (an extended Kalman filter), not a geomagnetic position fix with
``R = G^-1 Sigma G^-T``. Why: (1) the bias states enter the elements additively (``H = I``),
where a fix would mix them through G^-1; (2) a fix needs a square, invertible G and fails
where the contours are nearly parallel (the heading-free (I, F) contours are 23-27 deg apart on
the Pacific route), while the innovation form only ever multiplies by G: a weak direction is
simply little observed, with its covariance saying so; (3) three elements (D, I, F) weighted by
their declared noise need no special case. With ``y = S_meas - S_model(p) - b - m - (I kron h(psi)) c``:

    y ~ G J dx + db + dm + (I kron h(psi)) c + v,   H = [G J, I, I, I kron h(psi)],   R = diag(sigma_element^2)

where ``J = d(true east, north) / d(state)`` comes from the process model and G is the model's
gradient at the predicted position (:func:`companion.nav.field.element_gradient`), evaluated at
the centre of the averaging window. The field is linear to well below the noise over the few
kilometres of prior uncertainty, so one linearisation per step suffices. When the INS's own
attitude levels and turns the magnetometer (``attitude_from_ins``, FUS_ATT_INS: tilt, or tilt and
heading), its misalignment states are in the measurement too: ``+ A phi`` in y and ``G J + A`` in
H's process columns, A the misalignment's columns at the model's field there
(:func:`companion.nav.ins_error.misalignment_columns`; the heading error moves D one for one, a
tilt error moves D by about its size times tan I, and I).

Measurement noise (``r_source`` 1, FUS_R_SRC, the default): each period's averaged elements
carry their standard errors measured from the period's own scatter (the companion's robust
``1.4826 MAD / sqrt(n)``, :mod:`companion.nav.inclination`), and ``R = diag(se^2 + r_min^2)``:
the vehicle measures its own noise, so a noisier magnetometer (or a shaking accelerometer) is
described as it is instead of as declared; ``r_min`` (FUS_RMIN_DEG, FUS_RMIN_NT) stands for
what the scatter cannot show. The declared ``r_deg``, ``r_nt`` (FUS_R_DEG, FUS_R_NT) are used
where no standard error is measured, and always with ``r_source`` 0.

Bias noise: the biases walk at ``q`` per sqrt(hour) while quiet (0.002 deg, 2 nT by default;
the paper's ideal world declares 0.0002 deg, 0.2 nT: about what the main-field model's error
changes along a route, when nothing else does) plus ``q_d`` per sqrt(km) travelled, and, while a
disturbance is active, the active walk of :mod:`companion.nav.disturbance` on top: per element,
or along the field components through the elements' Jacobian (the default), optionally scaled by
covariance matching. Whether a disturbance is active is that module's
:class:`~companion.nav.disturbance.DisturbanceMonitor`'s to say (the innovations, or a declared
space-weather index). A quiet mission keeps the small ``q``, so it is not made worse by a
storm setting.

Covariances use filterpy's Joseph-form update; the predicted measurement is handed to filterpy
as ``z = y + H x`` so its ``z - H x`` is our innovation.
"""
from __future__ import annotations

import math

import numpy as np
from filterpy.kalman import KalmanFilter
from scipy.linalg import block_diag

from companion.nav.disturbance import COMPONENT_WALK, BiasWalk, DisturbanceMonitor, field_jacobian
from companion.nav.elements import ElementSet
from companion.nav.field import WorldMagneticModel, element_values_and_gradient
from companion.nav.filter_settings import BiasSpec, FilterSettings
from companion.nav.geo import enu_offset, offset_position
from companion.nav.ins_error import AttitudeSource, misalignment_columns
from companion.nav.local_error import LocalError
from companion.nav.process import InsProcess, ProcessModel
from companion.nav.small import inverse2, whiten

__all__ = [
    "HARMONIC_TERMS",
    "BiasSpec",
    "FilterSettings",
    "NavigationFilter",
    "harmonic_row",
    "measured_variance",
]

HARMONIC_TERMS = 4   # heading states per element: cos, sin of the heading and of twice it


def harmonic_row(heading_rad: float) -> np.ndarray:
    """``cos psi, sin psi, cos 2 psi, sin 2 psi``: how a body-frame calibration residual enters
    an element at true heading ``psi`` (rad), level. A hard-iron offset ``o`` appears in the
    north-east-down field as ``R(psi) o`` (first harmonic), a soft-iron residual ``S`` as
    ``R(psi) S R(psi)^T B`` (first harmonic through its vertical cross terms, second through
    its horizontal block); each element is linear in that field error to first order."""
    return np.array([math.cos(heading_rad), math.sin(heading_rad),
                     math.cos(2.0 * heading_rad), math.sin(2.0 * heading_rad)])


def measured_variance(standard_errors: np.ndarray, r_min: np.ndarray, r_declared: np.ndarray) -> np.ndarray:
    """Noise variance of each averaged element: its measured standard error with the floor
    ``r_min`` added in quadrature, ``se^2 + r_min^2``, or the declared ``r^2`` where no finite,
    non-negative one was measured (element units)."""
    se = np.asarray(standard_errors, dtype=float)
    measured = np.isfinite(se) & (se >= 0.0)
    return np.where(measured, np.where(measured, se, 0.0) ** 2 + r_min ** 2, r_declared ** 2)


class NavigationFilter:
    """Error-state filter over ``process`` plus the bias, local, heading and storm states (above)."""

    def __init__(self, process: ProcessModel, elements: ElementSet, settings: FilterSettings,
                 model: WorldMagneticModel, alt_m: float, year: float) -> None:
        self.process = process
        self.elements = elements
        self.settings = settings
        self.model = model
        self.alt_m, self.year = alt_m, year
        names = elements.names
        self.nb = len(names)
        b = settings.bias
        self._bias_sigma0 = b.per_element(names, b.sigma0_deg, b.sigma0_nt)
        self._walk = BiasWalk(names, b.per_element(names, b.q_deg_rth, b.q_nt_rth),
                              b.per_element(names, b.qd_deg_rkm, b.qd_nt_rkm),
                              b.per_element(names, b.qa_deg_rth, b.qa_nt_rth),
                              b.storm_walk if b.qa_mode == COMPONENT_WALK else None, self._field_ned)
        self.ns = len(self._walk.states)   # the storm's Gauss-Markov components, states
        self.local = LocalError(b.per_element(names, b.local_deg, b.local_nt)[:self.nb if b.has_local else 0],
                                b.local_length_m, b.local_order)
        self.nl = self.local.n
        heading_sigma = b.per_element(names, b.heading_deg, b.heading_nt)
        self.nh = HARMONIC_TERMS * self.nb if np.any(heading_sigma > 0.0) else 0   # none for this element set
        self._heading_sigma = np.repeat(heading_sigma, HARMONIC_TERMS)[:self.nh]
        self._r_declared = b.per_element(names, settings.r_deg, settings.r_nt)
        self._r_min = b.per_element(names, settings.r_min_deg, settings.r_min_nt)
        self._r = np.diag(self._r_declared ** 2)
        n = process.n + self.nb + self.nl + self.nh + self.ns
        kf = KalmanFilter(dim_x=n, dim_z=self.nb)
        if self.nb == 2:
            kf.inv = inverse2   # S^-1 of a pair in closed form (filterpy's documented hook)
        kf.x = np.zeros((n, 1))
        kf.P = block_diag(process.p0, np.diag(self._bias_sigma0 ** 2), self.local.initial_covariance(),
                          np.diag(self._heading_sigma ** 2), np.zeros((self.ns, self.ns)))
        # measured minus model beyond the position, from the state: the bias plus the local error
        # plus the heading harmonics (their columns follow the heading: set_heading) plus the
        # storm's Gauss-Markov components (their columns are J's: _storm_columns)
        self._total = np.hstack([np.zeros((self.nb, process.n)), np.eye(self.nb),
                                 self.local.columns(self.nb), np.zeros((self.nb, self.nh)),
                                 np.zeros((self.nb, self.ns))])
        self._storm_states = slice(n - self.ns, n)
        self.heading_known = False
        # the INS misalignment states the measured field carries (FUS_ATT_INS; _carry_attitude)
        self._attitude = list(AttitudeSource.columns(settings.attitude_from_ins)) \
            if isinstance(process, InsProcess) else []
        self.kf = kf
        # predict's block-diagonal Phi and Q_d: the bias and heading states are constants (the
        # identity; the heading states have no noise), the rest is filled in each step
        self._transition, self._noise = np.eye(n), np.zeros((n, n))
        self._bias_block = slice(process.n, process.n + self.nb)
        self._local = slice(process.n + self.nb, process.n + self.nb + self.nl)
        self.monitor = DisturbanceMonitor()
        self.last_nis = math.nan
        self.qa_scale = self.storm_scale = 1.0   # covariance matching: qa_adapt's, a declared storm's (storm_adapt)

    # --- state --------------------------------------------------------------------------------
    @property
    def x(self) -> np.ndarray:
        return self.kf.x[:, 0]

    @property
    def bias(self) -> np.ndarray:
        """Estimated element biases (measured minus model at the true position: the bias states
        plus the local model error), element units."""
        return self._total @ self.x

    @property
    def bias_sigma(self) -> np.ndarray:
        return np.sqrt(np.diag(self._total @ self.kf.P @ self._total.T))

    def beyond_position_covariance(self, standard_errors: np.ndarray | None = None) -> np.ndarray:
        """Covariance (element units) of what a measurement carries beyond the position: the biases'
        uncertainty at the current heading plus R; through G^-1 that of a bias-corrected fix."""
        return self._total @ self.kf.P @ self._total.T + self.measurement_noise(standard_errors)

    def position(self, ins_lat_deg: float = math.nan, ins_lon_deg: float = math.nan) -> tuple[float, float]:
        """The fused position (degrees); the INS position is needed with the INS process model."""
        return self.process.position(self.x, ins_lat_deg, ins_lon_deg)

    def covariance_en(self, lat_deg: float) -> np.ndarray:
        """2 x 2 covariance of the position estimate, east/north, m^2 (FUS_BQA_SADAPT 3: scaled by the
        declared storm's variance factor, :meth:`DisturbanceMonitor.variance_factor`)."""
        j = self._j(lat_deg)
        return j @ self.kf.P @ j.T * (self.monitor.variance_factor() if self.settings.bias.storm_adapt == 3 else 1.0)

    def _j(self, lat_deg: float) -> np.ndarray:
        return np.hstack([self.process.jacobian(lat_deg), np.zeros((2, self.nb + self.nl + self.nh + self.ns))])

    def set_heading(self, heading_rad: float) -> None:
        """The vehicle's true heading over the window measured next (rad; NaN: not known): the heading
        states' columns, ``cos psi, sin psi, cos 2 psi, sin 2 psi`` (zero when not known, the residual
        then measurement noise, :meth:`measurement_noise`)."""
        if not self.nh:
            return
        self.heading_known = math.isfinite(heading_rad)
        row = harmonic_row(heading_rad) if self.heading_known else np.zeros(HARMONIC_TERMS)
        first = self.process.n + self.nb + self.nl
        for element in range(self.nb):   # block diagonal: element e's own four coefficients
            start = first + HARMONIC_TERMS * element
            self._total[element, start:start + HARMONIC_TERMS] = row

    def _h(self, gradient: np.ndarray, lat_deg: float) -> np.ndarray:
        """Jacobian of the elements with respect to the state: ``G J`` (plus the INS misalignment's
        columns, FUS_ATT_INS) then the bias and local error states, which enter additively."""
        k = self.process.n
        return np.hstack([gradient @ self.process.jacobian(lat_deg) + self._total[:, :k], self._total[:, k:]])

    def _carry_attitude(self, lat_deg: float, lon_deg: float) -> None:
        """The INS misalignment's columns (:func:`~companion.nav.ins_error.misalignment_columns`) here."""
        if self._attitude:
            ned = self.model.ned_and_slopes(lat_deg, lon_deg, self.alt_m, self.year)[0]
            columns = misalignment_columns(field_jacobian(self.elements.names, *ned), ned)
            self._total[:, self._attitude] = columns[:, self._attitude]

    def snapshot(self) -> tuple:
        """Everything a step changes, to go back to (:meth:`restore`)."""
        return (self.kf.x.copy(), self.kf.P.copy(), self.process.snapshot(), self.monitor.snapshot(),
                self.last_nis, self.qa_scale, self.storm_scale)

    def restore(self, state: tuple) -> None:
        x, p, process, monitor, self.last_nis, self.qa_scale, self.storm_scale = state
        self.kf.x, self.kf.P = x.copy(), p.copy()
        self.process.restore(process)
        self.monitor.restore(monitor)

    # --- predict ------------------------------------------------------------------------------
    def predict(self, dt_s: float, vel_en_mps: np.ndarray, lat_deg: float,
                position_deg: tuple[float, float] | None = None) -> None:
        """Propagate over ``dt_s`` with the (commanded) velocity at latitude ``lat_deg``.
        ``position_deg``: where the vehicle is believed to be (lat, lon), for the field the
        active walk along the components is taken at (the last one given when None)."""
        if dt_s <= 0.0:
            return
        if position_deg is not None:
            self._walk.position = (float(position_deg[0]), float(position_deg[1]))
        phi, q_d = self.process.transition(dt_s, lat_deg, np.asarray(vel_en_mps, dtype=float))
        k = self.process.n
        transition, noise = self._transition, self._noise   # block diagonals, the constant blocks kept
        transition[:k, :k], noise[:k, :k] = phi, q_d
        distance_m = math.hypot(*vel_en_mps) * dt_s
        distance_km = distance_m / 1000.0
        along_components = self._walk.along_components(self.monitor)
        jacobian = self._storm_columns() if along_components else None
        noise[self._bias_block, self._bias_block] = self._walk.noise(dt_s, distance_km, self.monitor, self.qa_scale,
                                                                     jacobian, self.storm_scale)
        if self.ns:   # the storm's Gauss-Markov components: driven while declared, fading after
            decay, driven, cross = self._walk.storm_states_noise(dt_s, along_components, jacobian, self.storm_scale)
            transition[self._storm_states, self._storm_states] = np.diag(decay)
            noise[self._storm_states, self._storm_states] = driven
            noise[self._bias_block, self._storm_states] = cross
            noise[self._storm_states, self._bias_block] = np.transpose(cross)
        if self.nl:   # Gauss-Markov in the distance travelled (:mod:`companion.nav.local_error`)
            transition[self._local, self._local], noise[self._local, self._local] = self.local.transition(distance_m)
        self.kf.predict(F=transition, Q=noise)
        self.process.advance(self.x, dt_s, vel_en_mps)

    def _storm_columns(self) -> np.ndarray:
        """The elements' d / d(N, E, Z) where the vehicle is believed to be; the Gauss-Markov
        storm states' measurement columns are set from it."""
        jacobian = self._walk.jacobian()
        if self.ns:
            self._total[:, self._storm_states] = jacobian[:, self._walk.states]
        return jacobian

    def _field_ned(self, lat_deg: float, lon_deg: float) -> tuple[float, float, float]:
        field = self.model.elements(lat_deg, lon_deg, self.alt_m, self.year)
        return float(field.x_nt), float(field.y_nt), float(field.z_nt)

    # --- updates ------------------------------------------------------------------------------
    def measurement_noise(self, standard_errors: np.ndarray | None = None) -> np.ndarray:
        """R of one element measurement: with ``r_source`` 1 the period's measured standard
        errors with the floor ``r_min`` added in quadrature, ``R = diag(se^2 + r_min^2)``, and the
        declared noise for an element without a finite measured one; with ``r_source`` 0 (or no
        standard errors) the declared ``diag(r^2)``."""
        if self.settings.r_source != 1 or standard_errors is None:
            r = self._r
        else:
            r = np.diag(measured_variance(standard_errors, self._r_min, self._r_declared))
        if self.nh and not self.heading_known:   # the residual at an unknown heading: E|row|^2 = 2
            r = r + np.diag(2.0 * self._heading_sigma[::HARMONIC_TERMS] ** 2)
        return r

    def update_position(self, lat_deg: float, lon_deg: float, sigma_m: float,
                        ins_lat_deg: float = math.nan, ins_lon_deg: float = math.nan) -> None:
        """A position fix (a GPS start), 1-sigma ``sigma_m`` per axis."""
        here = self.position(ins_lat_deg, ins_lon_deg)
        y = np.array(enu_offset(here[0], here[1], lat_deg, lon_deg), dtype=float)
        self._update(y, self._j(here[0]), np.eye(2) * sigma_m ** 2)

    def reset_position(self, lat_deg: float, lon_deg: float, sigma_m: float,
                       ins_lat_deg: float = math.nan, ins_lon_deg: float = math.nan) -> None:
        """Re-anchor the estimate at (lat, lon) with 1-sigma ``sigma_m`` per axis
        (:mod:`companion.nav.reanchor`): the position's variance is first inflated by the square
        of the distance to it, so the position update below moves the estimate there almost
        whole instead of by the small step its own covariance would allow; bias and other states
        keep what they have learned beyond their correlation with position."""
        here = self.position(ins_lat_deg, ins_lon_deg)
        distance2 = float(np.sum(np.square(enu_offset(here[0], here[1], lat_deg, lon_deg))))
        spread = np.linalg.pinv(self._j(here[0]))              # position (m) -> state
        self.kf.P = self.kf.P + spread @ spread.T * (distance2 + sigma_m ** 2)
        self.update_position(lat_deg, lon_deg, sigma_m, ins_lat_deg, ins_lon_deg)

    def update_elements(self, measured: np.ndarray, lag_en_m: np.ndarray | None = None,
                        ins_lat_deg: float = math.nan, ins_lon_deg: float = math.nan,
                        standard_errors: np.ndarray | None = None,
                        at_centre: tuple[np.ndarray, np.ndarray] | None = None) -> float:
        """The averaged elements, referred to the window centre ``lag_en_m`` behind the current
        position, with their measured standard errors (:meth:`measurement_noise`); returns the
        normalised innovation squared (NIS). ``at_centre``: the model's elements and G at that
        centre (:meth:`window_centre`) when the caller has evaluated them already."""
        y, h, r = self._innovation(measured, lag_en_m, ins_lat_deg, ins_lon_deg, standard_errors, at_centre)
        nis, whitened = self._update(y, h, r)
        self.last_nis = nis
        was_active = self.monitor.active
        if self.monitor.observe(whitened) and self.settings.bias.qa_adapt:   # covariance matching
            self.qa_scale = self._walk.matched_scale(self.qa_scale, self.monitor, was_active)
        self.storm_scale = self._walk.storm_matched(self.storm_scale, self.monitor, self.settings.bias.storm_adapt)
        return nis

    def innovation_nis(self, measured: np.ndarray, lag_en_m: np.ndarray | None = None,
                       ins_lat_deg: float = math.nan, ins_lon_deg: float = math.nan,
                       standard_errors: np.ndarray | None = None,
                       at_centre: tuple[np.ndarray, np.ndarray] | None = None) -> float:
        """The NIS ``y^T S^-1 y`` the element measurement would have, without updating: the gate judged
        in the filter's own uncertainty (a far fix is no blunder to an estimate that knows it is uncertain)."""
        y, h, r = self._innovation(measured, lag_en_m, ins_lat_deg, ins_lon_deg, standard_errors, at_centre)
        s = h @ self.kf.P @ h.T + r
        return float(y @ np.linalg.solve(s, y))

    def window_centre(self, lag_en_m: np.ndarray | None = None, ins_lat_deg: float = math.nan,
                      ins_lon_deg: float = math.nan) -> tuple[float, float]:
        """The window centre ``lag_en_m`` (east, north m) behind the estimate (degrees)."""
        lag = np.zeros(2) if lag_en_m is None else np.asarray(lag_en_m, dtype=float)
        lat, lon = self.position(ins_lat_deg, ins_lon_deg)
        centre = offset_position(lat, lon, -float(lag[0]), -float(lag[1]))
        return float(centre[0]), float(centre[1])

    def _innovation(self, measured, lag_en_m, ins_lat_deg, ins_lon_deg, standard_errors, at_centre=None):
        """(y, H, R) of an element measurement at the window centre ``lag_en_m`` behind the estimate;
        the elements of :meth:`ElementSet.measured_rows` (F set aside in a storm, or without an index)."""
        lat = self.position(ins_lat_deg, ins_lon_deg)[0]
        if at_centre is None or self._attitude:
            centre = self.window_centre(lag_en_m, ins_lat_deg, ins_lon_deg)
            self._carry_attitude(*centre)
            if at_centre is None:
                at_centre = element_values_and_gradient(self.model, self.elements, *centre, self.alt_m, self.year)
        values, g = at_centre
        h = self._h(g, lat)
        y = self.elements.difference(np.asarray(measured, dtype=float), values + self.bias)
        r = self.measurement_noise(standard_errors)
        if len(rows := list(self.elements.measured_rows(self.monitor.declared, self.monitor.index_quiet))) < self.nb:
            return y[rows], h[rows], r[np.ix_(rows, rows)]
        return y, h, r

    def calibrate(self, measured: np.ndarray, ins_lat_deg: float = math.nan, ins_lon_deg: float = math.nan,
                  standard_errors: np.ndarray | None = None) -> float:
        """Start-up calibration at a known position: the start-up average observes the biases.

        The bias prior is set from the calibration innovation itself, per element
        ``var_b = clip(y^2 - r^2, (r/10)^2, sigma0^2)`` (the method-of-moments estimate of the
        bias variance, the positive-part James-Stein shrinkage): an innovation at the noise level
        says the model and sensor agree, and the filter does not carry the start-up average's own
        noise into the whole mission as a bias (0.2-0.6 km on the Pacific route); a large one
        (a calibration residual, crust, model error) is taken almost whole. The local model-error
        states keep their stationary variance and the bias takes the rest,
        ``var_b = clip(y^2 - r^2 - sigma_local^2, ...)``: what is carried from the start is the
        calibration, not the crust under the start. A storm declared at the start is treated
        alike: its Gauss-Markov components start at their stationary variance, and the bias takes
        what is left; so is the INS misalignment's share (FUS_ATT_INS). Then the usual update.
        Returns the NIS of the calibration measurement."""
        lat, lon = self.position(ins_lat_deg, ins_lon_deg)
        self._walk.position = (float(lat), float(lon))
        self._carry_attitude(lat, lon)
        expected = self.elements.values(self.model.elements(lat, lon, self.alt_m, self.year)) + self.bias
        y = self.elements.difference(np.asarray(measured, dtype=float), expected)
        r2 = np.diag(self.measurement_noise(standard_errors))
        local = np.zeros(self.nb)
        local[:self.local.elements] = self.local.sigma ** 2     # the local error at the start is part of y
        storm = np.zeros(self.ns)
        k = self.process.n
        attitude = self._total[:, :k]                # so is the INS misalignment's share (FUS_ATT_INS)
        beyond = local + np.einsum("ij,jk,ik->i", attitude, self.kf.P[:k, :k], attitude)
        if self.ns and self.monitor.declared:   # so is a declared storm's Gauss-Markov part
            storm = self._walk.storm.initial_variance()
            columns = self._storm_columns()[:, self._walk.states]
            beyond += np.einsum("ij,j,ij->i", columns, storm, columns)
        var = np.clip(y ** 2 - r2 - beyond, r2 / 100.0, self._bias_sigma0 ** 2)
        self.kf.P[k:, :] = 0.0
        self.kf.P[:, k:] = 0.0
        self.kf.P[k:, k:] = block_diag(np.diag(var), self.local.initial_covariance(),
                                       np.diag(np.concatenate([self._heading_sigma ** 2, storm])))
        return self.update_elements(measured, np.zeros(2), ins_lat_deg, ins_lon_deg, standard_errors)

    def _update(self, y: np.ndarray, h: np.ndarray, r: np.ndarray) -> tuple[float, np.ndarray]:
        z = (y + h @ self.x).reshape(-1, 1)
        self.kf.update(z, R=r, H=h)
        whitened = whiten(self.kf.S, y)
        self.kf.x = self.process.reset(self.x).reshape(-1, 1)
        return float(whitened @ whitened), whitened
