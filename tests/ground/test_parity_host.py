"""The parity contract's host-independence (docs/parity.md): what feeds a run is computed without
BLAS/LAPACK, whose kernels OpenBLAS picks by CPU at run time, so a run's inputs have the same bits
on every x86-64 host; and the closed-form 3 x 3 inverse that replaced ``numpy.linalg.inv``."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from conftest import ROOT, random_unit_quaternions
from gnc_common.compiled import inverse3_stack
from spacecraft_sim.core.wheels import ReactionWheels, allocation_matrix

#: A child prints a digest of every array the set-up path makes from the scenarios (reference,
#: inertia inverse, wheel allocation, initial state): the inputs of every run, node and campaign.
_DIGEST = """
import hashlib, numpy as np
from sappc.scenario import load_scenario
from sappc.offline.compiled_loop import prepare
h = hashlib.sha256()
for name in ("paper_tracking", "paper_tracking_wheels", "paper_tracking_flight"):
    inp = prepare(load_scenario(f"config/scenarios/{name}.yaml"))
    for a in (inp.grid.ref_q, inp.grid.ref_w, inp.grid.ref_wd, inp.plant.J_inv, inp.actuator.G_pinv, inp.actuator.G, inp.plant.x0, inp.controller.coef, inp.controller.prm, inp.disturbance.table):
        h.update(np.ascontiguousarray(a).tobytes())
print(h.hexdigest())
"""


def _digest(coretype: str | None) -> str:
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_CORETYPE"}
    if coretype is not None:
        env["OPENBLAS_CORETYPE"] = coretype
    proc = subprocess.run([sys.executable, "-c", _DIGEST], cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    return proc.stdout.strip()


def test_a_runs_inputs_do_not_depend_on_the_blas_kernel_the_cpu_picks() -> None:
    """``OPENBLAS_CORETYPE`` forces OpenBLAS's kernels for another CPU (Prescott and Nehalem run on
    any x86-64 CPU); before the set-up path was written out, the reference quaternion (scipy's
    DOP853 steps through ``np.dot``) and the wheel allocation differed in their last bits between
    them and the host's own kernels."""
    host = _digest(None)
    assert _digest("Prescott") == host
    assert _digest("Nehalem") == host


def test_the_closed_form_inverse_is_an_inverse_to_its_conditioning() -> None:
    """``J J^-1 = I`` to ``cond(J)`` rounding units, on random SPD inertias and a stack of them."""
    rng = np.random.default_rng(4)
    q = random_unit_quaternions(rng, 50)
    x, y, z, w = q.T
    R = np.stack([np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
                  np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
                  np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1)], -2)
    moments = rng.uniform(1.0, 100.0, (50, 3))
    J = R @ (moments[:, :, None] * np.transpose(R, (0, 2, 1)))
    J_inv = inverse3_stack(J)
    assert J_inv.shape == (50, 3, 3)
    cond = moments.max(axis=1) / moments.min(axis=1)
    residual = np.abs(J @ J_inv - np.eye(3)).max(axis=(1, 2))
    assert np.all(residual <= 16 * cond * np.finfo(float).eps)
    np.testing.assert_array_equal(inverse3_stack(J[7]), J_inv[7])  # one matrix: the same bits as in a stack
    with pytest.raises(ValueError, match="3, 3"):
        inverse3_stack(np.eye(4))


def test_the_allocation_is_the_minimum_norm_right_inverse() -> None:
    """``G G^+ = I`` and ``G^+`` equals numpy's pseudo-inverse to rounding, for the pyramid and a skewed set."""
    for axes in ("pyramid", ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0), (1.0, 2.0, 3.0), (-0.5, 0.1, 0.9))):
        G = ReactionWheels(spin_axes_B=axes, spin_inertia_kg_m2=0.05, max_torque_Nm=0.2, max_speed_rad_s=600.0).G
        Gp = allocation_matrix(G)
        np.testing.assert_allclose(G @ Gp, np.eye(3), rtol=0, atol=8 * np.finfo(float).eps)
        np.testing.assert_allclose(Gp, np.linalg.pinv(G), rtol=0, atol=8 * np.finfo(float).eps)
