"""The measuring chain's linear blocks as frequency responses (the bench runs in periodic steady
state, so each harmonic is multiplied by its response; exact, and no discretisation to argue about).

- Load cell + frame: two masses.  m1 (actuator + load-cell top) rides on the load cell's stiffness
  k1 over the frame mass m2, which sits on the floor through k2.  The actuator pulls m1 with +F and
  the mover's mount pulls the frame with -(1 - kappa) F (kappa: the part of the reaction the frame's
  mode does not feel; the mass ratio m2/m1 sets how much the frame's mode shows).  The piezo's
  charge follows its deformation: the reading is k1 (x1 - x2).  With a rigid frame this is the
  paper's single mode (fn, zeta); the frame adds its own mode, and k1 is set so the cell's mode
  stays at fn.
- Charge amplifier: a high-pass of time constant tau (the charge leaks through the feedback
  resistor), then the datasheet's 2nd-order low-pass.
- Flux integrator: an inverting op-amp integrator, R_in and C, with a finite open-loop DC gain
  and an optional feedback resistor; the output divided by the sense turns reads Phi.
"""

from __future__ import annotations

import numpy as np


def load_cell_frame_response(omega: np.ndarray, fn_hz: float | None, zeta: float,
                             frame: dict | None) -> np.ndarray:
    """Load-cell force over actuator force at each omega (rad/s); ``fn_hz`` None = a rigid cell."""
    w = np.asarray(omega, float)
    if fn_hz is None and frame is None:
        return np.ones(w.shape, complex)
    m1 = 1.0  # kg: the actuator and the load cell's top plate; only ratios matter below
    f1 = fn_hz if fn_hz is not None else 200e3  # a rigid cell: its mode far above anything recorded
    k1 = m1 * (2 * np.pi * f1) ** 2
    c1 = 2 * zeta * np.sqrt(k1 * m1)
    if frame is None:
        return k1 / (k1 - m1 * w**2 + 1j * w * c1)
    m2 = float(frame["mass_ratio"]) * m1
    k1 = m1 * m2 / (m1 + m2) * (2 * np.pi * f1) ** 2  # the cell's mode stays at fn on a frame that moves
    c1 = 2 * zeta * np.sqrt(k1 * m1 * m2 / (m1 + m2))
    wf = 2 * np.pi * float(frame["frequency_Hz"])
    k2 = (m1 + m2) * wf**2  # the whole assembly on the frame's spring
    c2 = 2 * float(frame["zeta"]) * np.sqrt(k2 * (m1 + m2))
    kappa = float(frame["coupling"])
    out = np.empty(w.shape, complex)
    for i, wi in enumerate(w):
        z1 = k1 + 1j * wi * c1
        mat = np.array([[z1 - m1 * wi**2, -z1], [-z1, z1 + k2 + 1j * wi * c2 - m2 * wi**2]])
        x = np.linalg.solve(mat, np.array([1.0, -(1 - kappa)], complex))
        out[i] = k1 * (x[0] - x[1])
    return out


def charge_amp_response(omega: np.ndarray, lpf_hz: float | None, lpf_zeta: float,
                        tau_s: float | None) -> np.ndarray:
    """Output over load-cell force: optional first-order high-pass, optional 2nd-order low-pass."""
    s = 1j * np.asarray(omega, float)
    h = np.ones(s.shape, complex)
    if lpf_hz is not None:
        w0 = 2 * np.pi * lpf_hz
        h = h * w0**2 / (s**2 + 2 * lpf_zeta * w0 * s + w0**2)
    if tau_s is not None:
        h = h * (s * tau_s) / (1 + s * tau_s)
    return h


def integrator_response(omega: np.ndarray, r_in_ohm: float, c_f: float, dc_gain: float | None,
                        r_feedback_ohm: float | None) -> np.ndarray:
    """Measured flux over true flux for the inverting integrator after the sense coil.

    Ideal: V_out = -(1/(R_in C)) integral U_c, U_c = -N2 dPhi/dt, scaled by R_in C / N2: gain 1.
    Real: V_out / U_c = -(Z_f / R_in) / (1 + (1 + Z_f / R_in) / A0), Z_f = R_f || 1/(sC)."""
    s = 1j * np.asarray(omega, float)
    out = np.ones(s.shape, complex)
    nz = s != 0
    s = s[nz]
    zc = 1 / (s * c_f)
    zf = zc if r_feedback_ohm is None else (r_feedback_ohm * zc) / (r_feedback_ohm + zc)
    h = -(zf / r_in_ohm)
    if dc_gain is not None:
        h = h / (1 + (1 + zf / r_in_ohm) / dc_gain)
    # the ideal chain: U_c = -s Phi (per turn), times -1/(s R_in C), times R_in C: 1
    out[nz] = -h * s * r_in_ohm * c_f
    out[~nz] = 0.0  # an integrator has no DC: the flux channel is AC only
    return out
