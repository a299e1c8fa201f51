"""The status page in a real browser: headless Chromium driven by Selenium (Debian's chromium,
chromium-driver, python3-selenium) against idm-web and a real idmd on the simulated stage. The
position shown follows a move, the plot and the region map are drawn, STOP on the page stops a
move, the jog buttons jog while pressed and stop when released (or by STOP), the speed-limit field
sets MOVE:VELocity and shows idmd's refusal, and a screenshot is kept in the build tree
(tests/web/status-page.png)."""
import os
import re
import time

import pytest
from selenium import webdriver
from selenium.webdriver.chrome.options import Options
from selenium.webdriver.chrome.service import Service
from selenium.webdriver.common.action_chains import ActionChains
from selenium.webdriver.common.by import By

from conftest import BUILD, ask, mean_position, send, wait_done, wait_for

ARTIFACT_DIR = os.path.join(BUILD, "tests", "web")


@pytest.fixture(scope="module")
def browser():
    options = Options()
    options.binary_location = os.environ.get("IDM_CHROMIUM", "/usr/bin/chromium")
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                "--window-size=1280,1400", "--disable-extensions"):
        options.add_argument(arg)
    service = Service(os.environ.get("IDM_CHROMEDRIVER", "/usr/bin/chromedriver"))
    driver = webdriver.Chrome(service=service, options=options)
    driver.set_page_load_timeout(60)
    yield driver
    driver.quit()


def shown_position_m(driver, axis=1):
    """The position the page shows, as a person reads it ("12.3456 µm"), in metres."""
    shown = driver.find_elements(By.ID, "pos-%d" % axis)
    if not shown:
        return None
    text = shown[0].text
    m = re.fullmatch(r"(-?\d+\.\d+) µm", text.strip())
    return float(m.group(1)) * 1e-6 if m else None


def test_the_shown_position_follows_a_move(lab, restore, browser):
    daemon, _, web = lab
    browser.get(web.url + "/")
    assert browser.title == "idm status"
    wait_for("the connection shown",
             lambda: browser.find_element(By.ID, "conn").text == "connected to idmd", 30)
    wait_for("a position shown", lambda: shown_position_m(browser) is not None, 30)
    assert browser.find_element(By.ID, "state-1").text == "IDLE"
    start = mean_position(daemon)
    assert abs(shown_position_m(browser) - start) < 0.05e-6
    target = start + 40e-6
    send(daemon, "MOVE:ABS %.12g" % target)
    wait_done(daemon)
    arrived = mean_position(daemon)
    # Shown to 0.1 nm; the readings scatter by a count (10 nm) around the mean.
    wait_for("the page to show the arrived position",
             lambda: abs((shown_position_m(browser) or 0) - arrived) < 0.05e-6, 30)
    assert browser.find_element(By.ID, "target-1").text == "%.4f µm" % (target * 1e6)
    assert "position valid" in browser.find_element(By.ID, "status-1").text
    # The plot has the last minute in it, and the region map is drawn.
    wait_for("the plot's history to span the move", lambda: browser.execute_script(
        "const h = view.history[1] || []; if (!h.length) return false;"
        "const xs = h.map(p => p[1]); return Math.max(...xs) - Math.min(...xs) > 30e-6;"), 30)
    wait_for("the region map", lambda: browser.execute_script(
        "const c = document.getElementById('regions-1'); if (!c) return false;"
        "const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;"
        "let green = 0, grey = 0; for (let i = 0; i < d.length; i += 4) {"
        " if (d[i+1] > d[i] + 40 && d[i+1] > d[i+2] + 40) green++;"
        " if (d[i] == 189 && d[i+1] == 189 && d[i+2] == 189) grey++; }"
        "return green > 100 && grey > 100;"), 30)
    os.makedirs(ARTIFACT_DIR, exist_ok=True)
    path = os.path.join(ARTIFACT_DIR, "status-page.png")
    if os.path.exists(path):
        os.unlink(path)
    assert browser.save_screenshot(path)
    with open(path, "rb") as f:
        assert f.read(8) == b"\x89PNG\r\n\x1a\n"


def test_stop_on_the_page_stops_a_move(lab, restore, browser):
    daemon, _, web = lab
    browser.get(web.url + "/")
    wait_for("the STOP button", lambda: browser.find_elements(By.ID, "stop-all"), 30)
    start = mean_position(daemon)
    target = 4e-3 if start < 0 else -4e-3
    send(daemon, "MOVE:ABS %.12g" % target)
    wait_for("the page to show MOVING",
             lambda: browser.find_element(By.ID, "state-1").text in ("MOVING", "SETTLING"), 30)
    browser.find_element(By.ID, "stop-all").click()
    wait_done(daemon, 10)
    stopped = mean_position(daemon)
    assert abs(stopped - target) > 1e-3, (start, stopped, target)
    assert browser.find_element(By.ID, "message").text == ""
    wait_for("the page to show IDLE", lambda: browser.find_element(By.ID, "state-1").text == "IDLE",
             10)


def test_a_move_from_the_page(lab, restore, browser):
    daemon, _, web = lab
    browser.get(web.url + "/")
    wait_for("the move input", lambda: browser.find_elements(By.ID, "target-input-1"), 30)
    box = browser.find_element(By.ID, "target-input-1")
    box.clear()
    box.send_keys("12.5")
    browser.find_element(By.ID, "move-1").click()
    wait_for("the daemon's target", lambda: ask(daemon, "MOVE?")[0] == "1.25e-05", 10)
    wait_done(daemon)
    wait_for("the page to show the position",
             lambda: abs((shown_position_m(browser) or 0) - 12.5e-6) < 0.05e-6, 30)
    box.clear()
    box.send_keys("99999")  # 0.1 m: past the soft limits
    browser.find_element(By.ID, "move-1").click()
    wait_for("the daemon's refusal shown",
             lambda: "-222" in browser.find_element(By.ID, "message").text, 10)


def test_the_speed_limit_from_the_page(lab, restore, browser):
    daemon, _, web = lab
    browser.get(web.url + "/")
    wait_for("the speed field", lambda: browser.find_elements(By.ID, "speed-input-1"), 30)
    wait_for("no limit shown", lambda: browser.find_element(By.ID, "speed-limit-1").text == "none",
             10)
    box = browser.find_element(By.ID, "speed-input-1")
    try:
        box.clear()
        box.send_keys("400")
        browser.find_element(By.ID, "speed-1").click()
        wait_for("the daemon's speed limit", lambda: ask(daemon, "MOVE:VEL?")[0] == "0.0004", 10)
        wait_for("the page to show it",
                 lambda: browser.find_element(By.ID, "speed-limit-1").text == "400 µm/s", 10)
        assert browser.find_element(By.ID, "message").text == ""
        box.clear()
        box.send_keys("2000000")  # 2 m/s: past idmd's range
        browser.find_element(By.ID, "speed-1").click()
        wait_for("the daemon's refusal shown",
                 lambda: "-222" in browser.find_element(By.ID, "message").text, 10)
        shown = browser.find_element(By.ID, "message").text
        assert shown.startswith("speed limit: -222,") and "MOVE:VELocity" in shown, shown
        assert "allowed [0, 1] m/s" in shown, shown
        assert ask(daemon, "MOVE:VEL?")[0] == "0.0004"
        box.clear()
        box.send_keys("fast")
        browser.find_element(By.ID, "speed-1").click()
        wait_for("the page's own refusal", lambda: browser.find_element(By.ID, "message").text ==
                 "speed limit: a speed in µm/s is needed (0: no limit)", 10)
    finally:
        send(daemon, "MOVE:VEL 0")


def test_jog_buttons_jog_while_pressed(lab, restore, browser):
    """Pressed, a jog button jogs (idmd's JOG toward that soft limit); released, the axis stops
    short of the limit (STOPPED); pressed again and stopped with the axis's STOP while still
    held, it stops too."""
    daemon, _, web = lab
    browser.get(web.url + "/")
    wait_for("the jog buttons", lambda: browser.find_elements(By.ID, "jog-pos-1"), 30)
    send(daemon, "MOVE:ABS 0")  # well inside the travel, wherever an earlier test left it
    wait_done(daemon)
    start = mean_position(daemon)
    lower, upper = start - 1e-3, start + 1e-3
    send(daemon, "LIM %.12g,%.12g" % (lower, upper))
    send(daemon, "MOVE:VEL 4e-4")
    window = float(ask(daemon, "MOVE:WIND?")[0])
    try:
        jog = browser.find_element(By.ID, "jog-pos-1")
        actions = ActionChains(browser)
        actions.click_and_hold(jog).perform()
        wait_for("the jog toward the upper limit",
                 lambda: abs(float(ask(daemon, "MOVE?")[0]) - (upper - window)) < 1e-12, 10)
        wait_for("the page to show MOVING",
                 lambda: browser.find_element(By.ID, "state-1").text in ("MOVING", "SETTLING"), 10)
        assert "active" in jog.get_attribute("class")
        wait_for("progress", lambda: mean_position(daemon, 2) > start + 50e-6, 10)
        actions.release(jog).perform()
        wait_done(daemon, 10)
        released = mean_position(daemon)
        assert ask(daemon, "MOVE:RES?")[0].startswith("STOPPED,")
        assert start + 50e-6 < released < upper - 100e-6, (start, released, upper)
        assert "active" not in jog.get_attribute("class")
        wait_for("the page to show IDLE",
                 lambda: browser.find_element(By.ID, "state-1").text == "IDLE", 10)
        # At rest it stays: the release sent one STOP, nothing more moves it.
        time.sleep(0.5)
        assert abs(mean_position(daemon) - released) < 0.5e-6

        back = browser.find_element(By.ID, "jog-neg-1")
        actions = ActionChains(browser)
        actions.click_and_hold(back).perform()
        wait_for("the jog toward the lower limit",
                 lambda: abs(float(ask(daemon, "MOVE?")[0]) - (lower + window)) < 1e-12, 10)
        wait_for("progress back", lambda: mean_position(daemon, 2) < released - 50e-6, 10)
        # STOP while the button is still held (the page's script clicks it: one pointer).
        browser.execute_script("document.getElementById('stop-1').click();")
        wait_done(daemon, 10)
        stopped = mean_position(daemon)
        assert ask(daemon, "MOVE:RES?")[0].startswith("STOPPED,")
        assert lower + 100e-6 < stopped < released - 50e-6, (lower, stopped, released)
        actions.release(back).perform()
        wait_done(daemon, 10)
        assert browser.find_element(By.ID, "message").text == ""
    finally:
        send(daemon, "MOVE:VEL 0")


def test_a_read_only_page_has_no_controls(lab, browser):
    _, web, _ = lab
    browser.get(web.url + "/")
    wait_for("a position shown", lambda: shown_position_m(browser) is not None, 30)
    assert not browser.find_elements(By.ID, "stop-all")
    assert not browser.find_elements(By.ID, "move-1")
    for control in ("jog-pos-1", "jog-neg-1", "speed-input-1", "speed-1"):
        assert not browser.find_elements(By.ID, control), control
    # The speed limit is shown there too (read, not set).
    wait_for("the speed limit shown",
             lambda: browser.find_element(By.ID, "speed-limit-1").text == "none", 10)
    assert "read-only" in browser.find_element(By.ID, "control").text
