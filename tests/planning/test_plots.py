"""Figures (issue 17): the 3-D path plot magnifies a deviation by a stated round factor."""

from __future__ import annotations

import numpy as np
import pytest

from planning.cli import _plots


def _line(deviation: float):
    s = np.linspace(0.0, 1.0, 201)
    p_d = np.stack([0.6 + 0.5 * s, 0.1 + 0.0 * s, 1.0 + 0.0 * s], -1)  # 0.5 m along x
    p_e = p_d + deviation * np.stack([0 * s, np.sin(7 * s), np.cos(7 * s)], -1)  # |deviation| constant
    return p_d, p_e


@pytest.mark.parametrize("deviation,scale", [(3.6e-8, 1e6), (1.1e-6, 2e4), (2.4e-5, 2e3), (0.0, 1.0), (0.1, 1.0)])
def test_deviation_scale_is_round_and_shows_the_deviation(deviation, scale):
    p_d, p_e = _line(deviation)
    k = _plots.deviation_scale(p_d, p_e)
    assert k == pytest.approx(scale, rel=1e-12)
    largest = k * np.max(np.linalg.norm(p_e - p_d, axis=-1))
    if k > 1:  # magnified to 4 ... 10 % of the 0.5 m extent
        assert 0.04 * 0.5 <= largest <= 0.1 * 0.5


def test_path_plot_is_written(tmp_path):
    p_d, p_e = _line(3.6e-8)
    r_d = np.broadcast_to(np.eye(3), (len(p_d), 3, 3))
    out = _plots.trajectory_3d(p_d, p_e, tmp_path / "path.png", "Line: tool path", r_d)
    assert out.stat().st_size > 10_000
