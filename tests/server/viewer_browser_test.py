#!/usr/bin/python3
"""The web viewer in a real browser (headless Debian chromium via selenium).

Runs a daemon with --default-epsilon 0.02 that wants a bearer token (typed
into the page) and holds spot plus a copy of it named "bessie" (listed
first). The page must open on spot, at the server's default epsilon (it
sends none itself), wait for the graph, and for two clicked points show the
gRPC distance for the same specs (exposed as data- attributes), a path tube
one can see and the path's length; in field mode, a colour bar whose last
tick is the gRPC field's maximum. Switching meshes while one loads must never
show the old mesh's state. Saves screenshots into OUT_DIR.

Usage: viewer_browser_test.py BUILD_BIN_DIR SOURCE_DIR OUT_DIR
"""
import json
import math
import os
import re
import shutil
import sys
import tempfile
import time
import unittest
import urllib.request

BIN, SRC, OUT = sys.argv[1], sys.argv[2], sys.argv[3]
sys.path.insert(0, os.path.join(SRC, "client", "python"))
from geodesic_client import Client  # noqa: E402
from selenium import webdriver  # noqa: E402
from selenium.webdriver.chrome.service import Service  # noqa: E402
from selenium.webdriver.common.action_chains import ActionChains  # noqa: E402
from selenium.webdriver.common.by import By  # noqa: E402
from selenium.webdriver.common.keys import Keys  # noqa: E402
from selenium.webdriver.support.ui import Select, WebDriverWait  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import daemon_ports  # noqa: E402

DEFAULT_EPS = 0.02  # the daemon's --default-epsilon; the page must not pick its own
TOKEN = "viewer-token"
OTHER = "bessie"    # spot again under a name that sorts before "spot"
LARGE = "calf"      # spot again, listed to the page as a mesh of 300,000 vertices

# Runs before the page's own scripts: records every fetch the page makes,
# can hold back those whose URL contains a key of window.__delay, to catch the
# page mid-load, and can make the listing claim more vertices for a mesh
# (sessionStorage "vertices": {name: count}) than it has.
FETCH_SPY = """
window.__requests = [];
window.__delay = {};
const claimed = JSON.parse(sessionStorage.getItem('vertices') || '{}');
const realFetch = window.fetch.bind(window);
window.fetch = async (url, options = {}) => {
  window.__requests.push({url: String(url), method: options.method || 'GET',
                          body: options.body || null});
  for (const [key, ms] of Object.entries(window.__delay)) {
    if (String(url).includes(key)) {
      await new Promise((r) => setTimeout(r, ms));
      // Not aborted on a switch: the late answer arrives, and the page itself
      // must see that it belongs to a mesh no longer selected.
      return realFetch(url, {...options, signal: undefined});
    }
  }
  const res = await realFetch(url, options);
  if (!String(url).endsWith('v1/meshes') || !res.ok) return res;
  const listing = await res.json();
  for (const m of listing.meshes) if (m.name in claimed) m.vertices = claimed[m.name];
  return new Response(JSON.stringify(listing), {status: res.status, headers: res.headers});
};
"""

# Records what the panel and the loading indicator show after every change.
PANEL_SPY = """
window.__seen = [];
const ids = ['mesh-title', 'mesh-info', 'graph-state', 'distance', 'path-length', 'picked',
             'status', 'busy-text', 'legend'];
const snap = () => {
  const text = ids.map((id) => document.getElementById(id).textContent).join(' | ');
  const g = document.getElementById('graph-state');
  window.__seen.push({t: performance.now(), text, graphMesh: g.dataset.mesh,
                      graphState: g.dataset.state,
                      title: document.getElementById('mesh-title').dataset.mesh});
};
const observer = new MutationObserver(snap);
for (const id of ['panel', 'busy', 'legend']) {
  observer.observe(document.getElementById(id),
                   {subtree: true, childList: true, characterData: true, attributes: true});
}
snap();
"""

# Pixels of the WebGL canvas (its drawing buffer is preserved) whose colour is
# the path's magenta: red well above green and above blue. The beige surface,
# the green and blue end markers and the white background all fail the test.
COUNT_PATH_PIXELS = """
const c = document.getElementById('canvas');
const copy = document.createElement('canvas');
copy.width = c.width;
copy.height = c.height;
const g = copy.getContext('2d');
g.drawImage(c, 0, 0);
const d = g.getImageData(0, 0, c.width, c.height).data;
let n = 0;
for (let i = 0; i < d.length; i += 4) if (d[i] - d[i + 1] > 90 && d[i] - d[i + 2] > 30) ++n;
return n;
"""

COLORBAR_COLOURS = """
const bar = document.getElementById('colorbar');
const d = bar.getContext('2d').getImageData(0, 0, bar.width, bar.height).data;
const seen = new Set();
for (let i = 0; i < d.length; i += 4) seen.add(`${d[i]},${d[i + 1]},${d[i + 2]}`);
return seen.size;
"""


def start_daemon(work):
    """(process, log, gRPC port, HTTP port) of the viewer's daemon."""
    with open(f"{work}/token", "w") as f:
        f.write(TOKEN)
    log = open(f"{work}/daemon.log", "w+")
    daemon, ports = daemon_ports.start_daemon(
        BIN, work, ["--graph-dir", f"{work}/graphs", "--log-level", "warning",
                    "--pseudo-vertex-limit", "0", "--auth-token-file",
                    f"{work}/token", "--default-epsilon", str(DEFAULT_EPS)],
        stderr=log, http=True)
    return daemon, log, ports["grpc"], ports["http"]


def face_point(spec, positions, faces):
    """xyz of an f:FACE:B0,B1,B2 spec: barycentrics over the face's corners in file order."""
    m = re.fullmatch(r"f:(\d+):([^,]+),([^,]+),([^,]+)", spec)
    f, bary = int(m.group(1)), [float(m.group(k)) for k in (2, 3, 4)]
    corners = [positions[3 * faces[3 * f + k]:3 * faces[3 * f + k] + 3] for k in range(3)]
    return [sum(bary[k] * corners[k][i] for k in range(3)) for i in range(3)]


class ViewerTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.work = tempfile.mkdtemp()
        cls.daemon, cls.log, grpc_port, cls.http_port = start_daemon(cls.work)
        cls.base = f"http://127.0.0.1:{cls.http_port}"
        cls.client = Client(f"127.0.0.1:{grpc_port}", timeout=60, token=TOKEN)
        cls.client.register_mesh(OTHER, "spot.obj")
        cls.client.register_mesh(LARGE, "spot.obj")
        options = webdriver.ChromeOptions()
        options.binary_location = "/usr/bin/chromium"
        for flag in ["--headless=new", "--no-sandbox", "--disable-dev-shm-usage",
                     "--window-size=1000,700", "--use-angle=swiftshader",
                     "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist",
                     f"--user-data-dir={cls.work}/chromium"]:
            options.add_argument(flag)
        cls.browser = webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=options)
        cls.browser.set_page_load_timeout(30)
        cls.browser.execute_cdp_cmd("Page.addScriptToEvaluateOnNewDocument", {"source": FETCH_SPY})

    @classmethod
    def tearDownClass(cls):
        cls.browser.quit()
        cls.client.close()
        daemon_ports.stop(cls.daemon)
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

    def attr(self, element_id, name):
        return self.browser.find_element(By.ID, element_id).get_attribute(name)

    def click_canvas(self, dx, dy):
        canvas = self.browser.find_element(By.ID, "canvas")
        ActionChains(self.browser).move_to_element_with_offset(canvas, dx, dy).click().perform()

    def open_page(self):
        """Loads the page, typing the token if the page asks for it, until spot's graph is ready."""
        b = self.browser
        b.get(f"{self.base}/")
        if not b.execute_script("return sessionStorage.getItem('geodesicd-token')"):
            # The daemon wants a bearer token: the page says so until one is typed.
            self.wait(lambda d: "UNAUTHENTICATED" in d.find_element(By.ID, "status").text,
                      what="the missing token to be reported")
            b.find_element(By.ID, "token").send_keys(TOKEN + Keys.TAB)
        self.wait(lambda d: self.attr("graph-state", "data-state") == "READY"
                  and self.attr("graph-state", "data-mesh") == "spot"
                  and self.attr("canvas", "data-mesh") == "spot"
                  and not d.find_element(By.ID, "busy").is_displayed(),
                  what="spot's geometry and graph")

    def geometry(self, mesh):
        req = urllib.request.Request(f"{self.base}/v1/meshes/{mesh}/geometry",
                                     headers={"Authorization": f"Bearer {TOKEN}"})
        with urllib.request.urlopen(req, timeout=60) as r:
            geo = json.load(r)
        return geo["positions"], geo["faces"]

    def pick_pair(self, what):
        # The cow's cheek and its flank, in the view the page frames.
        self.click_canvas(-60, -50)
        self.click_canvas(95, 80)
        return self.wait(lambda d: d.find_element(By.ID, "distance")
                         if self.attr("distance", "data-value") else False, what=what)

    def test_large_mesh_gets_its_graph_only_on_request(self):
        b = self.browser
        b.get(f"{self.base}/")
        b.execute_script(f"sessionStorage.setItem('vertices', '{{\"{LARGE}\": 300000}}')")
        try:
            self.open_page()
            b.execute_script("window.__requests = []")
            Select(b.find_element(By.ID, "mesh")).select_by_value(LARGE)
            self.wait(lambda d: self.attr("graph-state", "data-state") == "ABSENT"
                      and self.attr("graph-state", "data-mesh") == LARGE
                      and self.attr("canvas", "data-mesh") == LARGE,
                      what="the large mesh without a graph")
            self.assertIn("Build graph", b.find_element(By.ID, "graph-state").text)
            self.assertIn("300,000", b.find_element(By.ID, "graph-state").text)
            self.assertEqual(b.find_element(By.ID, "status").text, "")
            self.assertFalse(b.find_element(By.ID, "busy").is_displayed())
            posts = lambda: [r for r in b.execute_script("return window.__requests")
                             if r["method"] == "POST" and f"/meshes/{LARGE}/graph" in r["url"]]
            self.assertEqual(posts(), [])
            self.assertFalse([g for g in self.client.graphs() if g.mesh == LARGE])
            b.save_screenshot(f"{OUT}/viewer_large.png")
            # Asked for, it is built at the server's default epsilon.
            b.find_element(By.ID, "build").click()
            self.wait(lambda d: self.attr("graph-state", "data-state") == "READY"
                      and self.attr("graph-state", "data-mesh") == LARGE,
                      what="the large mesh's graph")
            self.assertEqual(float(self.attr("graph-state", "data-eps")), DEFAULT_EPS)
            self.assertEqual(len(posts()), 1)
            self.assertNotIn("eps", json.loads(posts()[0]["body"]))
        finally:
            b.execute_script("sessionStorage.removeItem('vertices')")

    def test_path_field_and_default_epsilon(self):
        b = self.browser
        self.open_page()
        # Opens on the sample mesh although another name sorts first.
        options = [o.get_attribute("value") for o in Select(b.find_element(By.ID, "mesh")).options]
        self.assertEqual(options[0], OTHER)
        self.assertEqual(Select(b.find_element(By.ID, "mesh")).first_selected_option
                         .get_attribute("value"), "spot")
        self.assertEqual(self.attr("mesh-title", "data-mesh"), "spot")
        self.assertEqual(float(self.attr("progress", "value")), 1.0)
        self.assertFalse(b.find_element(By.ID, "busy").is_displayed())

        # The server's default epsilon: the field stays empty, the page shows
        # the graph's echoed epsilon and never sends one of its own.
        self.assertEqual(self.attr("eps", "value"), "")
        self.assertEqual(float(self.attr("graph-state", "data-eps")), DEFAULT_EPS)
        self.assertEqual(float(self.attr("eps-default", "data-eps")), DEFAULT_EPS)
        self.assertIn(str(DEFAULT_EPS), b.find_element(By.ID, "eps-default").text)

        el = self.pick_pair("the distance")
        shown = float(el.get_attribute("data-value"))
        a, c = el.get_attribute("data-from"), el.get_attribute("data-to")
        self.assertRegex(a, r"^f:\d+:")
        self.assertRegex(c, r"^f:\d+:")
        self.assertNotEqual(a, c)
        self.assertGreater(shown, 0)
        self.assertEqual(float(el.get_attribute("data-eps")), DEFAULT_EPS)
        # The distance shown is the gRPC answer for the same points, asked
        # with the path as the page asks (the same distance as without it).
        distances, _ = self.client.distances("spot", [a], [c], epsilon=DEFAULT_EPS,
                                             with_path=True)
        expected = float(distances[0])
        self.assertEqual(shown, expected)
        self.assertAlmostEqual(float(el.text), expected, delta=expected * 1e-7)

        # The path's own length lies between the chord and the distance (up
        # to rounding in the 7th digit: the distance is summed by the server,
        # the polyline in the page from the xyz it was sent).
        positions, faces = self.geometry("spot")
        chord = math.dist(face_point(a, positions, faces), face_point(c, positions, faces))
        length = float(self.attr("path-length", "data-value"))
        self.assertGreater(length, chord)
        self.assertLessEqual(length, expected * (1 + 1e-7))
        self.assertGreater(length, expected * (1 - 1e-6))
        shown_length = re.search(r"[\d.]+", b.find_element(By.ID, "path-length").text)
        self.assertAlmostEqual(float(shown_length.group()), length, delta=length * 1e-7)
        self.assertGreaterEqual(int(self.attr("path-length", "data-points")), 2)
        # A tube thick enough to see, and its pixels are on screen.
        radius = float(self.attr("path-length", "data-radius"))
        diagonal = float(self.attr("path-length", "data-diagonal"))
        self.assertTrue(0.002 <= radius / diagonal <= 0.02, (radius, diagonal))
        time.sleep(0.3)  # a frame or two after the tube was added
        path_pixels = b.execute_script(COUNT_PATH_PIXELS)
        self.assertGreater(path_pixels, 300, "the path is hardly visible")
        b.save_screenshot(f"{OUT}/viewer_path.png")

        # A source in field mode: a colour bar whose last tick is the field's
        # largest finite distance, equal to the gRPC field's.
        b.find_element(By.ID, "mode-field").click()
        self.click_canvas(0, 0)
        legend = self.wait(lambda d: d.find_element(By.ID, "legend")
                           if self.attr("legend", "data-max") else False, what="the field")
        source = b.find_element(By.ID, "picked").text.replace("source ", "")
        field = self.client.field("spot", [source], epsilon=DEFAULT_EPS)
        top = float(field[[math.isfinite(x) for x in field]].max())
        self.assertEqual(float(legend.get_attribute("data-max")), top)
        bar = b.find_element(By.ID, "colorbar")
        self.assertTrue(legend.is_displayed() and bar.is_displayed())
        self.assertGreater(bar.size["width"], 100)
        self.assertGreater(bar.size["height"], 5)
        self.assertGreaterEqual(b.execute_script(COLORBAR_COLOURS), 10, "the bar has no gradient")
        ticks = b.find_elements(By.CSS_SELECTOR, "#ticks span")
        values = [float(t.get_attribute("data-value")) for t in ticks]
        self.assertGreaterEqual(len(values), 3)
        self.assertEqual(values[0], 0)
        self.assertEqual(values, sorted(values))
        self.assertEqual(values[-1], top)
        self.assertAlmostEqual(float(ticks[-1].text), top, delta=top * 1e-3)
        self.assertTrue(all(t.is_displayed() and t.text for t in ticks))
        self.assertAlmostEqual(float(self.attr("isolines", "data-spacing")), top / 20)
        b.save_screenshot(f"{OUT}/viewer_field.png")
        self.assertEqual(b.find_element(By.ID, "status").text, "")

        # Ticking "pseudo vertices" requests that graph and asks every query
        # of it: a path then equals the gRPC answer on the pseudo-vertex graph.
        b.find_element(By.ID, "pseudo").click()
        self.wait(lambda d: self.attr("graph-state", "data-pseudo") == "true"
                  and self.attr("graph-state", "data-state") == "READY",
                  seconds=120, what="the pseudo-vertex graph to be ready")
        self.assertEqual(float(self.attr("graph-state", "data-eps")), DEFAULT_EPS)
        b.find_element(By.ID, "mode-path").click()
        el = self.pick_pair("the distance on the pseudo-vertex graph")
        self.assertEqual(el.get_attribute("data-pseudo"), "true")
        a, c = el.get_attribute("data-from"), el.get_attribute("data-to")
        distances, _ = self.client.distances("spot", [a], [c], epsilon=DEFAULT_EPS,
                                             with_path=True, pseudo_vertices=True)
        self.assertEqual(float(el.get_attribute("data-value")), float(distances[0]))
        self.assertEqual(b.find_element(By.ID, "status").text, "")

        # Not one request carried an epsilon: the server's default applied to all.
        requests = b.execute_script("return window.__requests")
        api = [r for r in requests if "v1/meshes/" in r["url"]]
        self.assertTrue(any(r["method"] == "POST" for r in api))
        for r in api:
            self.assertNotIn("eps=", r["url"])
            if r["body"]:
                body = json.loads(r["body"])
                self.assertNotIn("eps", body, r)
                self.assertNotIn("epsilon", body, r)

    def test_switching_mid_load_never_shows_the_old_mesh(self):
        b = self.browser
        self.open_page()
        # A path on spot, so that there is state to leak.
        self.pick_pair("a distance on spot")
        b.execute_script(PANEL_SPY)
        # Bessie's answers are held back: the page is caught loading it.
        b.execute_script(f"window.__delay = {{'/meshes/{OTHER}/': 2500}}")
        Select(b.find_element(By.ID, "mesh")).select_by_value(OTHER)
        self.wait(lambda d: d.find_element(By.ID, "busy").is_displayed(), seconds=5,
                  what="the loading indicator")
        self.assertIn(f"Loading {OTHER}", b.find_element(By.ID, "busy-text").text)
        self.assertIn("geometry", self.attr("busy", "data-tasks"))
        # Already cleared of spot's state while bessie loads.
        self.assertEqual(self.attr("mesh-title", "data-mesh"), OTHER)
        self.assertNotEqual(self.attr("graph-state", "data-mesh"), "spot")
        self.assertEqual(self.attr("distance", "data-value"), "")
        self.assertEqual(self.attr("path-length", "data-value"), "")
        b.save_screenshot(f"{OUT}/viewer_loading.png")
        # Back to spot before bessie's geometry or graph has arrived.
        switched = b.execute_script("""
            const s = document.getElementById('mesh');
            s.value = 'spot';
            s.dispatchEvent(new Event('change'));
            return performance.now();""")
        self.wait(lambda d: self.attr("graph-state", "data-state") == "READY"
                  and self.attr("graph-state", "data-mesh") == "spot", what="spot again")
        time.sleep(3.5)  # bessie's held-back answers are due by now
        seen = b.execute_script("return window.__seen")
        after = [s for s in seen if s["t"] >= switched]
        self.assertTrue(after)
        for s in after:
            self.assertNotIn(OTHER, s["text"], s)
            self.assertNotEqual(s["graphMesh"], OTHER, s)
            self.assertEqual(s["title"], "spot", s)
        # Bessie was shown while it was selected, so the spy did see it.
        self.assertTrue(any(OTHER in s["text"] for s in seen if s["t"] < switched))
        self.assertEqual(self.attr("mesh-title", "data-mesh"), "spot")
        self.assertEqual(b.find_element(By.ID, "status").text, "")
        self.assertFalse(b.find_element(By.ID, "busy").is_displayed())


if __name__ == "__main__":
    unittest.main(argv=sys.argv[:1], verbosity=2)
