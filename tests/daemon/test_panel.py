# SPDX-License-Identifier: BSD-3-Clause
"""``tripod-daemon panel``: its own process beside a real daemon on loopback, driven by a real
browser (Debian's chromium + chromium-driver, headless, through Selenium): log in, see the packet
rate rise while real VLP-16 packets are replayed, mark a station and find the mark in the
recording; without the password the page and the actions are refused.

``TRIPOD_PANEL_SCREENSHOTS=DIR`` also writes the phone-sized screenshots (docs/ in the README).
"""

from __future__ import annotations

import http.cookiejar
import json
import os
import shutil
import ssl
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from daemon_helpers import (
    FakePty,
    RunningDaemon,
    free_tcp_port,
    loopback_config,
    read_pcap_udp,
    send_paced,
    udp_sender,
)
from tripod_daemon.certs import gen_certs
from tripod_daemon.panel import range_image
from tripod_daemon.panel.live import tilt_deg
from tripod_shared import witmotion
from tripod_shared.recording import RecordingReader

PASSWORD = "gloves-and-sun-42"
DUAL_RETURN_RATE = 1508  # VLP-16 packets/s in dual-return mode


def _payloads(velodyne_dir: Path) -> list[bytes]:
    return [p for _port, p in read_pcap_udp(velodyne_dir / "veloview-vlp16-20hz.pcap")
            if len(p) == 1206]


class Panel:
    """``tripod-daemon panel`` as its own process, for a daemon at ``endpoint``."""

    def __init__(self, tmp_path: Path, endpoint: str, password: str = PASSWORD):
        self.certs = tmp_path / "certs"
        if not (self.certs / "device.pem").exists():
            gen_certs(str(self.certs), ["localhost", "127.0.0.1"], [])
        self.cred = tmp_path / "panel-credentials"
        self.cred.write_text(f"operator:{password}\n")
        self.port = free_tcp_port()
        self.url = f"https://127.0.0.1:{self.port}"
        self.args = [sys.executable, "-m", "tripod_daemon", "panel", "--no-system-config",
                     "--listen", f"127.0.0.1:{self.port}", "--credentials", str(self.cred),
                     "--certificate", str(self.certs / "device.pem"),
                     "--private-key", str(self.certs / "device.key"), "--connect", endpoint]
        self.proc: subprocess.Popen | None = None
        self.ssl = ssl.create_default_context(cafile=str(self.certs / "ca.pem"))

    def __enter__(self) -> "Panel":
        self.proc = subprocess.Popen(self.args, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                     text=True)
        end = time.monotonic() + 30
        while time.monotonic() < end:
            assert self.proc.poll() is None, self.proc.stdout.read()
            try:
                self.get("/")
            except urllib.error.HTTPError:
                return self  # it answers (401 without a login)
            except OSError:
                time.sleep(0.1)
        raise RuntimeError("panel did not start")

    def __exit__(self, *exc) -> None:
        self.proc.terminate()
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self.proc.stdout.close()

    def opener(self, jar=None):
        return urllib.request.build_opener(
            urllib.request.HTTPSHandler(context=self.ssl),
            urllib.request.HTTPCookieProcessor(jar if jar is not None
                                               else http.cookiejar.CookieJar()))

    def get(self, path: str, opener=None):
        op = opener or self.opener()
        with op.open(self.url + path, timeout=5) as r:
            return r.status, r.read()

    def post(self, path: str, body: bytes, ctype: str, opener=None):
        op = opener or self.opener()
        req = urllib.request.Request(self.url + path, data=body,
                                     headers={"Content-Type": ctype}, method="POST")
        with op.open(req, timeout=10) as r:
            return r.status, r.read()


def _status(fn) -> int:
    try:
        return fn()[0]
    except urllib.error.HTTPError as exc:
        return exc.code


@pytest.fixture
def daemon(tmp_path):
    port = free_tcp_port()
    ep = f"tcp/127.0.0.1:{port}"
    cfg = loopback_config(tmp_path, zenoh={"enabled": True, "listen": [ep]},
                          status={"interval_s": 0.5})
    with RunningDaemon(cfg) as d:
        d.endpoint = ep
        yield d


def _marks(d) -> list[str]:
    d.stop()
    return [e.label for f in d.daemon.recorder.files for e in RecordingReader(f).events()
            if e.kind == "mark"]


# ---- without the password ------------------------------------------------------------------
def test_refused_without_the_password(tmp_path, daemon):
    with Panel(tmp_path, daemon.endpoint) as p:
        # HTTPS with the device's certificate (verified against the CA that signed it)
        code = _status(lambda: p.get("/"))
        assert code == 401
        try:
            p.get("/")
        except urllib.error.HTTPError as exc:
            page = exc.read().decode()
        assert 'name="password"' in page and "lidar-rate" not in page
        assert _status(lambda: p.get("/api/state")) == 401
        mark = lambda op=None: p.post("/api/control/mark", b'{"label": "intruder"}',  # noqa: E731
                                      "application/json", op)
        assert _status(mark) == 401
        # a wrong password gets the login page again, and no session
        jar = http.cookiejar.CookieJar()
        op = p.opener(jar)
        assert _status(lambda: p.post("/login", b"password=guess",
                                      "application/x-www-form-urlencoded", op)) == 401
        assert _status(lambda: mark(op)) == 401 and len(jar) == 0
        # the right one: a Secure, HttpOnly session cookie, then the state and actions
        assert p.post("/login", f"password={PASSWORD}".encode(),
                      "application/x-www-form-urlencoded", op)[0] == 200  # after the 303
        cookie = next(iter(jar))
        assert cookie.secure and cookie.has_nonstandard_attr("HttpOnly")
        st = json.loads(p.get("/api/state", op)[1])
        assert st["recording"]["recording"] is True
        # an action needs a JSON body (a cross-site form cannot send one)
        assert _status(lambda: p.post("/api/control/mark", b"label=x",
                                      "application/x-www-form-urlencoded", op)) == 415
        assert json.loads(mark(op)[1])["ok"] is True
    assert _marks(daemon) == ["intruder"]  # only the logged-in request


def test_refuses_to_start_without_password_or_certificate(tmp_path):
    base = [sys.executable, "-m", "tripod_daemon", "panel", "--no-system-config",
            "--listen", "127.0.0.1:1"]
    env = {k: v for k, v in os.environ.items() if k != "CREDENTIALS_DIRECTORY"}
    r = subprocess.run(base + ["--credentials", str(tmp_path / "none")], capture_output=True,
                       text=True, timeout=60, env=env)
    assert r.returncode == 2
    assert r.stderr.strip() == (f"tripod-daemon panel: refusing to serve the page without a "
                                f"password: credentials file {tmp_path / 'none'}: No such file "
                                "or directory")
    cred = tmp_path / "cred"
    cred.write_text("operator:x\n")
    r = subprocess.run(base + ["--credentials", str(cred)], capture_output=True, text=True,
                       timeout=60, env=env)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1
    assert "the page is served over HTTPS only" in r.stderr


# ---- the pieces the page is made of ---------------------------------------------------------
def test_range_image_of_a_real_rotation(velodyne_dir):
    pk = range_image.from_payloads(_payloads(velodyne_dir)[:400])
    rot = range_image.one_rotation(pk)
    az = range_image.azimuths_cdeg(rot)[:, 0]
    assert 36 <= len(rot) <= 40  # 754 packets/s (single return) at 20 Hz: ~38 a rotation
    assert az[0] < 1000 and az[-1] > 35000  # from the wrap to the next
    img = range_image.range_image(rot)
    assert img.shape == (16, 360) and img.dtype == np.float32
    hit = img > 0
    assert hit.mean() > 0.8  # an indoor scan: almost every direction returns
    assert 0.3 < np.median(img[hit]) < 30  # metres
    grey = range_image.to_grey(img)
    assert grey[hit].min() >= 1 and (grey[~hit] == 0).all()
    # a packet's block 0, laser 0 (-15 deg, bottom row) lands where its azimuth says
    blk = bytes(rot[10, :100])
    d0 = (blk[4] | (blk[5] << 8)) * 0.002
    col = ((blk[2] | (blk[3] << 8)) // 100) % 360
    assert d0 == 0 or any(abs(img[15, c] - d0) < 0.5 for c in (col, (col + 1) % 360))


def test_tilt_from_the_quaternion():
    t, r, p = tilt_deg(1.0, 0.0, 0.0, 0.0)
    assert (round(t, 6), round(r, 6), round(p, 6)) == (0.0, 0.0, 0.0)
    h = np.radians(10.0) / 2  # 10 deg about x (roll)
    t, r, p = tilt_deg(np.cos(h), np.sin(h), 0.0, 0.0)
    assert abs(t - 10.0) < 1e-9 and abs(r - 10.0) < 1e-9 and abs(p) < 1e-9
    h = np.radians(90.0) / 2  # a yaw does not tilt the head
    assert abs(tilt_deg(np.cos(h), 0.0, 0.0, np.sin(h))[0]) < 1e-9


# ---- a real browser -------------------------------------------------------------------------
def _browser():
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    chromium = shutil.which("chromium")
    driver = shutil.which("chromedriver")
    assert chromium and driver, "Debian chromium + chromium-driver needed (make setup)"
    o = webdriver.ChromeOptions()
    o.binary_location = chromium
    for a in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
              "--ignore-certificate-errors", "--no-first-run", "--disable-extensions"):
        o.add_argument(a)
    # a phone's screen: 360 x 740 CSS pixels (one device pixel each: the screenshots' size)
    o.add_experimental_option("mobileEmulation", {"deviceMetrics": {
        "width": 360, "height": 740, "pixelRatio": 1.0, "touch": True}})
    os.environ.setdefault("SE_OFFLINE", "true")  # never let Selenium fetch a driver
    return webdriver.Chrome(options=o, service=Service(executable_path=driver))


def _shot(drv, name: str, bottom: bool = False) -> None:
    """A 360 x 740 screenshot of what the phone shows (scrolled to the end with ``bottom``)."""
    out = os.environ.get("TRIPOD_PANEL_SCREENSHOTS")
    if not out:
        return
    Path(out).mkdir(parents=True, exist_ok=True)
    drv.execute_script("window.scrollTo(0, arguments[0] ? document.body.scrollHeight : 0)",
                       bottom)
    time.sleep(0.2)
    drv.save_screenshot(str(Path(out) / name))
    drv.execute_script("window.scrollTo(0, 0)")


@pytest.fixture
def imu_daemon(tmp_path):
    """A daemon with a WitMotion IMU on a pseudo-terminal and 150 MiB of free disk."""
    dev = FakePty(tmp_path / "imu")
    port = free_tcp_port()
    ep = f"tcp/127.0.0.1:{port}"
    cfg = loopback_config(tmp_path, zenoh={"enabled": True, "listen": [ep]},
                          imu={"url": str(dev.link), "driver": "witmotion"},
                          status={"interval_s": 0.5})
    try:
        with RunningDaemon(cfg, free_space=lambda _path: 150 << 20) as d:
            d.endpoint, d.imu_dev = ep, dev
            yield d
    finally:
        dev.close()


def _text(drv, css: str) -> str:
    from selenium.webdriver.common.by import By

    return "\n".join(e.text for e in drv.find_elements(By.CSS_SELECTOR, css))


def test_browser_login_live_rate_mark_and_refusal(tmp_path, imu_daemon, velodyne_dir):
    from selenium.webdriver.common.by import By
    from selenium.common.exceptions import StaleElementReferenceException
    from selenium.webdriver.support.ui import WebDriverWait

    daemon = imu_daemon
    payloads = _payloads(velodyne_dir)
    stop, imu_on = threading.Event(), threading.Event()
    h = np.radians(3.0) / 2  # the head rolled by 3 deg
    q_frame = witmotion.encode_quaternion(float(np.cos(h)), float(np.sin(h)), 0.0, 0.0)

    def replay():  # paced at the dual-return rate over loopback UDP, until told to stop
        s = udp_sender()
        while not stop.is_set():
            send_paced(s, daemon.data_addr, payloads[:300], DUAL_RETURN_RATE)

    def imu():  # 100 samples/s while imu_on
        while not stop.is_set():
            if imu_on.is_set():
                daemon.imu_dev.write(q_frame)
            time.sleep(0.01)

    with Panel(tmp_path, daemon.endpoint) as p:
        drv = _browser()
        t = threading.Thread(target=replay, daemon=True)
        ti = threading.Thread(target=imu, daemon=True)
        imu_on.set()
        ti.start()
        try:
            # the panel re-renders its lists each second: an element found just before a
            # re-render is stale when read, so the condition is looked at again
            wait = WebDriverWait(drv, 15, poll_frequency=0.2,
                                 ignored_exceptions=(StaleElementReferenceException,))
            drv.get(p.url + "/")
            # no session: the login page, nothing of the panel
            assert drv.find_elements(By.ID, "password") and not drv.find_elements(By.ID, "rec")
            r = drv.execute_async_script(
                "const done = arguments[0]; fetch('/api/control/mark', {method: 'POST', "
                "headers: {'Content-Type': 'application/json'}, body: '{}'})"
                ".then(r => done(r.status))")
            assert r == 401
            drv.find_element(By.ID, "password").send_keys(PASSWORD)
            drv.find_element(By.ID, "btn-login").click()
            wait.until(lambda d: d.find_element(By.ID, "conn").text == "live")

            def rate():
                txt = drv.find_element(By.ID, "lidar-rate").text
                return float(txt) if txt.replace(".", "").isdigit() else -1.0

            assert 0 <= rate() < 100  # nothing replayed yet
            t.start()
            wait.until(lambda d: rate() > 1000)
            wait.until(lambda d: "packets" in d.find_element(By.ID, "range-cap").text)
            assert "RECORDING" in drv.find_element(By.ID, "rec-state").text
            # the IMU: its state and the head's tilt from the quaternion; the disk warning
            wait.until(lambda d: d.find_element(By.ID, "imu-tilt").text == "3.0°")
            assert drv.find_element(By.ID, "imu-state").text == "ok"
            wait.until(lambda d: "Disk full in" in _text(d, "#warn-list li"))
            # the buttons are big enough for a gloved finger, and the page fits 360 px
            btn = drv.find_element(By.ID, "btn-mark")
            assert btn.size["height"] >= 64 and btn.size["width"] >= 300
            assert drv.execute_script("return document.documentElement.scrollWidth") <= 360
            _shot(drv, "panel-recording.png")

            drv.find_element(By.ID, "mark-label").send_keys("station A")
            btn.click()
            wait.until(lambda d: "Station marked" in d.find_element(By.ID, "toast").text)
            wait.until(lambda d: any("station A" in li.text for li in
                                     d.find_elements(By.CSS_SELECTOR, "#marks li")))
            # stop takes two taps: the first only arms it
            drv.find_element(By.ID, "btn-stop").click()
            assert drv.find_element(By.ID, "btn-stop").text == "Tap again"
            assert daemon.daemon.recorder.active
            _shot(drv, "panel-marked.png", bottom=True)
            # the IMU goes quiet: a warning in plain words
            imu_on.clear()
            wait.until(lambda d: "IMU silent for" in _text(d, "#warn-list li"))
            assert drv.find_element(By.ID, "imu-state").text == "stalled"
            # the session ends with a log-out: the page is refused again
            drv.find_element(By.CSS_SELECTOR, ".logout button").click()
            wait.until(lambda d: d.find_elements(By.ID, "password"))
        finally:
            stop.set()
            drv.quit()
            for th in (t, ti):
                if th.is_alive():
                    th.join(10)
    assert daemon.daemon.counts["lidar_data"] > 1000
    assert _marks(daemon) == ["station A"]


def test_settings_reach_a_daemon_with_the_secure_example_config(tmp_path, monkeypatch):
    """deploy/etc/daemon.secure.yaml (mutual TLS, logins) with the files the units' LoadCredential=
    hands over: the panel finds its password, the HTTPS certificate and a way in over TLS, and
    may control from this machine."""
    from tripod_daemon.client import control, open_session, query_status
    from tripod_daemon.config import load
    from tripod_daemon.panel import settings

    certs, creds = tmp_path / "certs", tmp_path / "creds"
    gen_certs(str(certs), ["tripod0.local"], [])
    creds.mkdir()
    for name in ("device.pem", "device.key", "ca.pem"):
        (creds / f"tripod_{name}").write_bytes((certs / name).read_bytes())
    (creds / "tripod_zenoh-users").write_text("operator:op\npanel:pw-1\n")
    (creds / "tripod_panel-credentials").write_text("panel:pw-1\n")
    monkeypatch.setenv("CREDENTIALS_DIRECTORY", str(creds))
    port = free_tcp_port()
    repo = Path(__file__).resolve().parents[2]
    cfg = load(str(repo / "deploy/etc/daemon.secure.yaml"), {
        "zenoh.listen": [f"tls/0.0.0.0:{port}"], "lidar.bind_address": "127.0.0.1",
        "lidar.data_port": 0, "lidar.position_port": 0, "lidar.receive_buffer_bytes": 1 << 20,
        "recording.directory": str(tmp_path / "rec"), "recording.min_free_bytes": 0},
        system_config=None)
    opts, cert, key, password = settings(cfg)
    assert (cert, key, password) == (str(creds / "tripod_device.pem"),
                                     str(creds / "tripod_device.key"), "pw-1")
    assert opts.endpoint == f"tls/127.0.0.1:{port}" and opts.credentials.user == "panel"
    assert opts.ca == str(creds / "tripod_ca.pem") and opts.certificate == cert
    with RunningDaemon(cfg) as d:
        s = open_session(opts)
        try:
            assert query_status(s, opts)["recording"] is True
            assert control(s, opts, "mark", "from the panel")["ok"] is True
        finally:
            s.close()
    assert _marks(d) == ["from the panel"]


def test_no_daemon_the_page_says_so_and_actions_fail_cleanly(tmp_path):
    port = free_tcp_port()  # nothing listens there
    with Panel(tmp_path, f"tcp/127.0.0.1:{port}") as p:
        jar = http.cookiejar.CookieJar()
        op = p.opener(jar)
        p.post("/login", f"password={PASSWORD}".encode(), "application/x-www-form-urlencoded", op)
        st = json.loads(p.get("/api/state", op)[1])
        assert st["connected"] is False
        assert st["warnings"][0].startswith("No connection to the daemon: ")
        try:
            p.post("/api/control/mark", b"{}", "application/json", op)
            raise AssertionError("mark without a daemon answered 200")
        except urllib.error.HTTPError as exc:
            assert exc.code == 503 and json.loads(exc.read())["ok"] is False
        assert p.proc.poll() is None  # still serving, retrying the connection
