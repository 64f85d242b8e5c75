"""Unit frequency / unit gain manifolds: build, file format, shipped set."""

from __future__ import annotations

import json

import numpy as np
import pytest

import mrftcli
from mrftcli.errors import InputError
from mrftcli.mrft.lprs import mrft_limit_cycle
from mrftcli.mrft.model import LoopModel
from mrftcli.mrft.ufm import (
    FORMAT_VERSION,
    SHIPPED_BETAS,
    ManifoldSet,
    build_manifold,
    build_manifolds,
    load_manifold,
    load_manifolds,
    save_manifold,
)


def test_build_save_load_round_trip(tmp_path):
    tp = np.geomspace(1e-2, 10, 31)
    td = np.geomspace(1e-1, 100, 41)
    m = build_manifold(-0.45, tp, td)
    path = save_manifold(m, tmp_path)
    assert path.name == "ufm_beta-0.450.npz"
    meta = json.loads((tmp_path / "ufm_beta-0.450.json").read_text())
    assert meta["format_version"] == FORMAT_VERSION
    assert meta["beta"] == -0.45
    assert meta["package_version"] == mrftcli.__version__
    assert meta["grid"]["tp"]["n"] == 31 and meta["grid"]["td"]["n"] == 41
    back = load_manifold(path)
    assert back.beta == -0.45
    np.testing.assert_array_equal(back.theta, m.theta)
    np.testing.assert_array_equal(back.amplitude, m.amplitude)
    np.testing.assert_array_equal(back.tp_n, tp)
    np.testing.assert_array_equal(back.td_n, td)


def test_manifold_points_are_plants_oscillating_at_unit_frequency():
    # a UFM point (tp, td, theta) is a plant that oscillates at exactly 1 rad/s (independent check
    # through the frequency search of mrft_limit_cycle), and the UGM is its amplitude (K Td = 1, h = 1)
    tp = np.geomspace(0.05, 2, 5)
    td = np.geomspace(0.5, 50, 5)
    m = build_manifold(-0.6, tp, td)
    for i in (0, 2, 4):
        for j in (0, 3):
            theta = float(m.theta[i, j])
            if theta <= 0:
                continue
            lc = mrft_limit_cycle(LoopModel(tp[i], td[j], theta, 1.0 / td[j]), -0.6)
            assert lc.omega == pytest.approx(1.0, rel=1e-5)
            assert lc.amplitude == pytest.approx(float(m.amplitude[i, j]), rel=1e-5)


def test_negative_theta_means_no_plant():
    m = build_manifold(-0.3, np.array([5.0, 50.0]), np.array([5.0, 500.0]))
    assert np.all(m.theta < 0)  # both lags already exceed the MRFT phase at unit frequency
    assert np.all(np.isnan(m.theta_physical()))


def test_shipped_set_covers_the_required_betas_and_size(repo_root):
    ms = load_manifolds()
    np.testing.assert_allclose(ms.betas, SHIPPED_BETAS)
    assert ms.betas[0] == pytest.approx(-0.9) and ms.betas[-1] == pytest.approx(-0.1)
    total = sum(p.stat().st_size for p in (repo_root / "manifolds").glob("ufm_beta*"))
    assert total < 10e6
    # range: DNN-MRFT plants (checks.md section 5) and Td/tau ~ 100 lie inside the grid
    for model in (LoopModel(0.015, 2.0, 0.0005), LoopModel(0.3, 0.2, 0.1), LoopModel(0.0499, 4.18, 0.042)):
        for beta in (-0.9, -0.1):
            lc = mrft_limit_cycle(model, beta)
            assert ms.tp_n[0] < model.Tp * lc.omega < ms.tp_n[-1]
            assert ms.td_n[0] < model.Td * lc.omega < ms.td_n[-1]


def test_interpolated_slice_between_betas_is_close_to_exact():
    ms = load_manifolds()
    tp = np.array([0.3, 0.5])
    td = np.array([3.0, 20.0])
    approx, amp = ms.evaluate(-0.63, tp, td)
    exact, amp_e = ms.evaluate(-0.63, tp, td, exact=True)
    np.testing.assert_allclose(approx, exact, rtol=5e-3)
    np.testing.assert_allclose(amp, amp_e, rtol=1e-3)


def test_bad_inputs(tmp_path):
    with pytest.raises(InputError, match="beta"):
        build_manifolds([-1.0])
    with pytest.raises(InputError, match="log-spaced"):
        build_manifold(-0.5, np.array([0.1, 0.2, 0.5]), np.geomspace(1, 10, 4))
    with pytest.raises(InputError, match="at least one"):
        build_manifolds([])
    bad = tmp_path / "ufm_beta-0.500.npz"
    bad.write_bytes(b"not a zip")
    with pytest.raises(InputError, match="cannot read"):
        load_manifold(bad)
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(InputError, match="no manifold files"):
        load_manifolds(empty)
    with pytest.raises(InputError, match="does not exist"):
        load_manifolds(tmp_path / "missing")


def test_manifold_set_needs_manifolds():
    with pytest.raises(InputError):
        ManifoldSet([])


def test_build_reports_progress_through_the_protocol_and_draws_nothing(capsys):
    seen = []
    grid = np.geomspace(0.1, 10, 9)
    ms = build_manifolds([-0.3, -0.6], grid, grid, progress=lambda done, total, stage="": seen.append((done, total, stage)))
    assert [m.beta for m in ms] == [-0.3, -0.6]
    assert seen == [(0, 2, "UFM"), (1, 2, "UFM"), (2, 2, "UFM")]
    out = capsys.readouterr()
    assert out.out == "" and out.err == ""
