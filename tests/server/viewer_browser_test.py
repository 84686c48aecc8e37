#!/usr/bin/python3
"""The web viewer in a real browser (headless Debian chromium via selenium).

Loads the page from a daemon's --http-listen (which wants a bearer token,
typed into the page), waits for the graph, clicks two points on the shaded
mesh and checks the distance the page shows against the gRPC answer for the
same specs (which the page exposes as data- attributes); then clicks a source
in field mode and checks the field's maximum against gRPC's. Saves
screenshots into the build directory.

Usage: viewer_browser_test.py BUILD_BIN_DIR SOURCE_DIR OUT_DIR
"""
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
import unittest

BIN, SRC, OUT = sys.argv[1], sys.argv[2], sys.argv[3]
sys.path.insert(0, os.path.join(SRC, "client", "python"))
from geodesic_client import Client  # noqa: E402
from selenium import webdriver  # noqa: E402
from selenium.webdriver.chrome.service import Service  # noqa: E402
from selenium.webdriver.common.action_chains import ActionChains  # noqa: E402
from selenium.webdriver.common.by import By  # noqa: E402
from selenium.webdriver.common.keys import Keys  # noqa: E402
from selenium.webdriver.support.ui import WebDriverWait  # noqa: E402

EPS = 0.01
TOKEN = "viewer-token"


def start_daemon(work):
    with open(f"{work}/token", "w") as f:
        f.write(TOKEN)
    log = open(f"{work}/daemon.log", "w+")
    daemon = subprocess.Popen(
        [f"{BIN}/geodesicd", "serve", "--listen", "127.0.0.1:0", "--http-listen", "127.0.0.1:0",
         "--graph-dir", f"{work}/graphs", "--log-level", "warning", "--auth-token-file",
         f"{work}/token"],
        stderr=log)
    deadline = time.time() + 30
    while time.time() < deadline:
        log.seek(0)
        text = log.read()
        grpc_port = re.search(r"serving on \S+ \(port (\d+)", text)
        http_port = re.search(r"http port (\d+)", text)
        if grpc_port and http_port:
            return daemon, log, int(grpc_port.group(1)), int(http_port.group(1))
        if daemon.poll() is not None:
            raise RuntimeError(f"daemon exited: {text}")
        time.sleep(0.05)
    daemon.kill()
    raise RuntimeError("daemon did not report its ports")


class ViewerTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.work = tempfile.mkdtemp()
        cls.daemon, cls.log, grpc_port, cls.http_port = start_daemon(cls.work)
        cls.client = Client(f"127.0.0.1:{grpc_port}", timeout=60, token=TOKEN)
        options = webdriver.ChromeOptions()
        options.binary_location = "/usr/bin/chromium"
        for flag in ["--headless=new", "--no-sandbox", "--disable-dev-shm-usage",
                     "--window-size=1000,700", "--use-angle=swiftshader",
                     "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist",
                     f"--user-data-dir={cls.work}/chromium"]:
            options.add_argument(flag)
        cls.browser = webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=options)
        cls.browser.set_page_load_timeout(30)

    @classmethod
    def tearDownClass(cls):
        cls.browser.quit()
        cls.client.close()
        cls.daemon.terminate()
        cls.daemon.wait(timeout=30)
        cls.log.close()
        shutil.rmtree(cls.work)

    def wait(self, condition, seconds=60, what="condition"):
        try:
            return WebDriverWait(self.browser, seconds, poll_frequency=0.1).until(condition)
        except Exception:
            self.browser.save_screenshot(f"{OUT}/viewer_failure.png")
            status = self.browser.find_element(By.ID, "status").text
            logs = self.browser.get_log("browser")
            self.fail(f"timed out waiting for {what}; status: {status!r}; console: {logs}")

    def click_canvas(self, dx, dy):
        canvas = self.browser.find_element(By.ID, "canvas")
        ActionChains(self.browser).move_to_element_with_offset(canvas, dx, dy).click().perform()

    def test_path_distance_equals_grpc_and_field_colours_the_mesh(self):
        b = self.browser
        b.get(f"http://127.0.0.1:{self.http_port}/")
        # The daemon wants a bearer token: the page says so until one is typed.
        self.wait(lambda d: "UNAUTHENTICATED" in d.find_element(By.ID, "status").text,
                  what="the missing token to be reported")
        b.find_element(By.ID, "token").send_keys(TOKEN + Keys.TAB)
        self.wait(lambda d: d.find_element(By.ID, "graph-state").get_attribute("data-state")
                  == "READY", what="the graph to be ready")
        self.assertEqual(float(b.find_element(By.ID, "progress").get_attribute("value")), 1.0)
        self.assertIn("spot", b.find_element(By.ID, "mesh").text)

        # Two points near the middle of the view, where the cow is.
        self.click_canvas(-40, -10)
        self.click_canvas(60, 40)
        el = self.wait(lambda d: d.find_element(By.ID, "distance")
                       if d.find_element(By.ID, "distance").get_attribute("data-value") else False,
                       what="the distance")
        shown = float(el.get_attribute("data-value"))
        a, c = el.get_attribute("data-from"), el.get_attribute("data-to")
        self.assertRegex(a, r"^f:\d+:")
        self.assertRegex(c, r"^f:\d+:")
        self.assertNotEqual(a, c)
        self.assertGreater(shown, 0)
        # The distance shown is the gRPC answer for the same points, asked
        # with the path as the page asks (the same distance as without it).
        distances, _ = self.client.distances("spot", [a], [c], epsilon=EPS, with_path=True)
        expected = float(distances[0])
        self.assertEqual(shown, expected)
        self.assertAlmostEqual(float(el.text), expected, delta=expected * 1e-7)
        b.save_screenshot(f"{OUT}/viewer_path.png")

        # A source in field mode: the legend reports the field's largest
        # finite distance, which must equal the gRPC field's.
        b.find_element(By.ID, "mode-field").click()
        self.click_canvas(0, 0)
        legend = self.wait(lambda d: d.find_element(By.ID, "legend")
                           if d.find_element(By.ID, "legend").get_attribute("data-max") else False,
                           what="the field")
        source = b.find_element(By.ID, "picked").text.replace("source ", "")
        field = self.client.field("spot", [source], epsilon=EPS)
        self.assertEqual(float(legend.get_attribute("data-max")), float(field.max()))
        b.save_screenshot(f"{OUT}/viewer_field.png")
        self.assertEqual(b.find_element(By.ID, "status").text, "")

        # Ticking "pseudo vertices" requests that graph and asks every query
        # of it: a path then equals the gRPC answer on the pseudo-vertex graph.
        b.find_element(By.ID, "pseudo").click()
        self.wait(lambda d: d.find_element(By.ID, "graph-state").get_attribute("data-pseudo")
                  == "true" and d.find_element(By.ID, "graph-state").get_attribute("data-state")
                  == "READY", seconds=120, what="the pseudo-vertex graph to be ready")
        b.find_element(By.ID, "mode-path").click()
        self.click_canvas(-40, -10)
        self.click_canvas(60, 40)
        el = self.wait(lambda d: d.find_element(By.ID, "distance")
                       if d.find_element(By.ID, "distance").get_attribute("data-value") else False,
                       what="the distance on the pseudo-vertex graph")
        self.assertEqual(el.get_attribute("data-pseudo"), "true")
        a, c = el.get_attribute("data-from"), el.get_attribute("data-to")
        distances, _ = self.client.distances("spot", [a], [c], epsilon=EPS, with_path=True,
                                             pseudo_vertices=True)
        self.assertEqual(float(el.get_attribute("data-value")), float(distances[0]))
        self.assertEqual(b.find_element(By.ID, "status").text, "")


if __name__ == "__main__":
    unittest.main(argv=sys.argv[:1], verbosity=2)
