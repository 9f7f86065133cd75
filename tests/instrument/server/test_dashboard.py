"""The dashboard's server side, without a browser: the page and BokehJS are served from
the installed packages, a browser's key offered as a WebSocket subprotocol is checked like
a header, frame messages carry the exposure and saturation, the axes' units are served.
The page itself is tested in a real Chromium (test_dashboard_browser.py)."""

from __future__ import annotations

import numpy as np
import pytest
from fastapi.testclient import TestClient
from starlette.websockets import WebSocketDisconnect

from instrument.bench.profile import parse_profile
from instrument.protocol import API_PREFIX as P
from instrument.protocol import MESSAGE_TYPES, decode
from instrument.run.storage import FrameData
from instrument.server.app import create_app
from instrument.server.dashboard import BOKEH_FILES, STATIC, bokeh_js_dir
from instrument.server.keys import KeyStore
from instrument.server.service import BenchService, _frame_message
from tests.instrument.server.helpers import fast_profile_text


@pytest.fixture
def app(tmp_path):
    """An app over a service whose bench is not connected (nothing here moves), with an
    observer key (so keys are required)."""
    profile = parse_profile(fast_profile_text(), source="fast sim")
    service = BenchService(profile, tmp_path / "runs", fsync=False, connect=False)
    token = KeyStore(service.db).add("olga", "observer")[1]
    with TestClient(create_app(service)) as http:
        yield http, token


def test_the_root_url_is_the_dashboard_and_its_files_come_from_the_packages(app):
    http, _ = app
    r = http.get("/")
    assert r.status_code == 200 and r.url.path == "/dashboard/"
    assert r.headers["content-type"].startswith("text/html")
    assert "/dashboard/bokeh/bokeh.min.js" in r.text and "https://" not in r.text
    for name in ("dashboard.js", "dashboard.css"):
        r = http.get(f"/dashboard/static/{name}")
        assert r.status_code == 200 and r.content == (STATIC / name).read_bytes()
    folder = bokeh_js_dir()
    assert folder is not None
    for name in BOKEH_FILES:
        r = http.get(f"/dashboard/bokeh/{name}")
        assert r.status_code == 200 and r.content == (folder / name).read_bytes()
        assert r.headers["content-type"].startswith("text/javascript")


@pytest.mark.parametrize("path", ["/dashboard/static/../__init__.py",
                                  "/dashboard/static/%2e%2e/__init__.py",
                                  "/dashboard/static/nothing.js",
                                  "/dashboard/bokeh/compiler.js",
                                  "/dashboard/bokeh/..%2F..%2F__init__.py"])
def test_nothing_outside_the_page_and_bokehs_two_files_is_served(app, path):
    http, _ = app
    assert http.get(path).status_code == 404


def test_a_browser_key_offered_as_a_subprotocol_is_checked_like_a_header(app):
    http, token = app
    with http.websocket_connect(f"{P}/events",
                                subprotocols=["scatterlab.v1", f"bearer.{token}"]) as ws:
        assert ws.accepted_subprotocol == "scatterlab.v1"
        hello = decode(ws.receive_text())
        assert hello.type == "hello" and hello.data["role"] == "observer"
        assert hello.data["name"] == "olga"
    for protocols in (["scatterlab.v1", "bearer.sl_wrong"], ["scatterlab.v1"]):
        with pytest.raises(WebSocketDisconnect) as err, \
                http.websocket_connect(f"{P}/events", subprotocols=protocols) as ws:
            ws.receive_text()
        assert err.value.code == 1008


def test_the_axes_units_need_a_key_and_name_every_axis(app):
    http, token = app
    assert http.get(f"{P}/bench/axes").status_code == 401
    r = http.get(f"{P}/bench/axes", headers={"Authorization": f"Bearer {token}"})
    assert r.status_code == 200
    axes = r.json()["axes"]
    assert set(axes) == {"sample_theta", "detector_theta", "camera_z"}
    # the bench is not connected: units unknown, limits from the profile
    assert axes["sample_theta"]["units"] is None
    assert axes["sample_theta"]["limits"][0] < axes["sample_theta"]["limits"][1]


def test_a_frame_message_says_its_exposure_and_saturated_fraction():
    data = np.zeros((64, 80), np.uint16)
    data[:4, :4] = 4095
    msg = _frame_message(7, FrameData(data, 2500.0, True, 0.0, 16 / data.size))
    assert msg["exposure_us"] == 2500.0
    assert msg["saturated"] == pytest.approx(16 / (64 * 80))
    assert set(MESSAGE_TYPES["frame"].fields) == set(msg)
