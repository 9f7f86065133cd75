"""The screenshot script renders every main view on the simulated bench, none blank."""

from __future__ import annotations

import numpy as np
import pytest
from PySide6.QtGui import QImage

from gui.screenshots import TYPE_I_VIEWS, VIEWS, render_all
from tests.gui.conftest import flush_deleted


def _pixels(path) -> np.ndarray:
    img = QImage(str(path)).convertToFormat(QImage.Format_RGB888)
    w, h = img.width(), img.height()
    buf = np.frombuffer(img.constBits(), np.uint8, count=img.sizeInBytes())
    return buf.reshape(h, img.bytesPerLine())[:, :3 * w].reshape(h, w, 3)


@pytest.mark.slow
def test_every_view_renders_and_none_is_blank(qtbot, tmp_path):
    shots = render_all(tmp_path)
    flush_deleted()
    assert tuple(shots) == VIEWS
    for name, path in shots.items():
        px = _pixels(path)
        assert px.shape[0] > 150 and px.shape[1] > 300, name
        colours = np.unique(px.reshape(-1, 3)[:: max(1, px.size // 3 // 200000)], axis=0)
        assert len(colours) > 50, f"{name} looks blank ({len(colours)} colours)"
        assert px.std() > 10, f"{name} looks blank"


@pytest.mark.slow
def test_the_type_i_bench_renders_its_arms_panel_and_view(qtbot, tmp_path):
    shots = render_all(tmp_path, bench="sim-type-i")
    flush_deleted()
    assert tuple(shots) == TYPE_I_VIEWS
    assert {p.name for p in shots.values()} == {"bench_type_i.png", "goniometer_type_i.png"}
    for name, path in shots.items():
        px = _pixels(path)
        assert px.shape[0] > 150 and px.shape[1] > 300, name
        assert px.std() > 10, f"{name} looks blank"


@pytest.mark.slow
def test_the_polarimetric_planner_picture_shows_the_front_with_a_row_chosen(qtbot,
                                                                            tmp_path):
    from gui.screenshots import POLARIMETRIC_VIEW, render_polarimetric_planner

    path = render_polarimetric_planner(tmp_path)
    flush_deleted()
    assert path.name == f"{POLARIMETRIC_VIEW}.png"
    px = _pixels(path)
    assert px.shape[0] > 150 and px.shape[1] > 300
    assert px.std() > 10, "the picture looks blank"
