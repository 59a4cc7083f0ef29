"""The operator page in a real browser: Chromium driven by ChromeDriver over the W3C WebDriver
protocol (a small client on the standard library: no Selenium to pin), against a tiny run that
waits for design 1's prototype. Run by cli/tests/operator_page.rs.

    python3 page_check.py PAGE_URL SCREENSHOT_PNG

Tokens come from the files named by PAGE_OPERATOR_TOKEN_FILE and PAGE_CLIENT_TOKEN_FILE (never
from arguments); PAGE_CA_FILE, when set, is the CA of an https page (Chromium is told to accept
the test's private CA; the forged requests verify against it). What it checks, in order:
  1. without a session the page is the login form, and no run data is shown;
  2. an unknown token is refused on the form;
  3. a client token views the waiting prototype with no button to answer it;
  4. forged POSTs are refused (403): no cookie; the client's own session and CSRF field;
     the operator's session without the CSRF field (what a cross-site form would send if the
     SameSite cookie went along);
  5. an operator token answers "as built" from the page with two measured dimensions changed,
     and the page says what was written.
Prints one JSON line: the as-built values entered.
"""

import base64
import json
import os
import socket
import ssl
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.parse
import urllib.request

ELEMENT = "element-6066-11e4-a52e-4f735466cecf"
AS_BUILT = {0: "1.05", 4: "0.95"}


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def call(method, url, body=None, timeout=60):
    data = None if body is None else json.dumps(body).encode()
    req = urllib.request.Request(url, data=data, method=method, headers={"Content-Type": "application/json"})
    try:
        with urllib.request.urlopen(req, timeout=timeout) as r:
            return json.loads(r.read() or b"{}").get("value")
    except urllib.error.HTTPError as e:
        raise RuntimeError(f"webdriver {method} {url}: {e.code} {e.read()[:400]!r}") from None


class Browser:
    def __init__(self, chromium, chromedriver, profile):
        self.port = free_port()
        self.driver = subprocess.Popen([chromedriver, f"--port={self.port}"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        self.base = f"http://127.0.0.1:{self.port}"
        for _ in range(200):
            try:
                if call("GET", self.base + "/status", timeout=2).get("ready"):
                    break
            except Exception:
                pass
            time.sleep(0.1)
        else:
            raise RuntimeError("chromedriver did not start")
        # As root in a sandbox, without the network: Chromium's flags of the machine's notes.
        args = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                "--disable-background-networking", "--disable-component-update", "--disable-sync",
                f"--user-data-dir={profile}", "--window-size=1300,2000"]
        if os.environ.get("PAGE_CA_FILE"):
            # The test's own CA is in no trust store Chromium reads.
            args.append("--ignore-certificate-errors")
        caps = {"capabilities": {"alwaysMatch": {"browserName": "chrome", "goog:chromeOptions": {"binary": chromium, "args": args}}}}
        self.sid = call("POST", self.base + "/session", caps)["sessionId"]
        self.s = f"{self.base}/session/{self.sid}"

    def close(self):
        try:
            call("DELETE", self.s)
        finally:
            self.driver.terminate()
            self.driver.wait(10)

    def go(self, url):
        call("POST", self.s + "/url", {"url": url})

    def all(self, css):
        return [e[ELEMENT] for e in call("POST", self.s + "/elements", {"using": "css selector", "value": css})]

    def one(self, css, wait=20.0):
        t = time.time()
        while True:
            found = self.all(css)
            if found:
                return found[0]
            if time.time() - t > wait:
                raise AssertionError(f"no element {css!r} on the page: {self.text('body')[:2000]}")
            time.sleep(0.1)

    def text(self, css):
        # The page replaces its panels as the run moves on (page.js): an element found just
        # before a replacement is stale when its text is asked for (seen on a loaded machine);
        # it is found again.
        for _ in range(50):
            found = self.all(css)
            if not found:
                return ""
            try:
                return call("GET", f"{self.s}/element/{found[0]}/text")
            except RuntimeError as e:
                if "stale element reference" not in str(e):
                    raise
            time.sleep(0.1)
        raise RuntimeError(f"{css!r} went stale 50 times running")

    def type(self, css, text, clear=False):
        e = self.one(css)
        if clear:
            call("POST", f"{self.s}/element/{e}/clear", {})
        call("POST", f"{self.s}/element/{e}/value", {"text": text})

    def click(self, css):
        call("POST", f"{self.s}/element/{self.one(css)}/click", {})

    def cookie(self, name):
        for c in call("GET", self.s + "/cookie"):
            if c["name"] == name:
                return c
        return None

    def screenshot(self, path):
        with open(path, "wb") as f:
            f.write(base64.b64decode(call("GET", self.s + "/screenshot")))


def post(url, fields, cookie=None):
    """A POST made outside the page (a forged request): its status and body."""
    data = urllib.parse.urlencode(fields).encode()
    headers = {"Content-Type": "application/x-www-form-urlencoded"}
    if cookie:
        headers["Cookie"] = cookie
    req = urllib.request.Request(url, data=data, method="POST", headers=headers)
    handlers = [NoRedirect]
    if os.environ.get("PAGE_CA_FILE"):
        handlers.append(urllib.request.HTTPSHandler(context=ssl.create_default_context(cafile=os.environ["PAGE_CA_FILE"])))
    opener = urllib.request.build_opener(*handlers)
    try:
        with opener.open(req, timeout=10) as r:
            return r.status, r.read().decode()
    except urllib.error.HTTPError as e:
        return e.code, e.read().decode()


class NoRedirect(urllib.request.HTTPRedirectHandler):
    def redirect_request(self, *args, **kwargs):
        return None


def wait_text(b, css, needle, wait=30.0):
    t = time.time()
    while needle not in b.text(css):
        if time.time() - t > wait:
            raise AssertionError(f"{css!r} never said {needle!r}; it says {b.text(css)!r}")
        time.sleep(0.2)


def login(b, url, token):
    b.go(url)
    b.type("#token", token)
    b.click("#login")


def main():
    url, shot = sys.argv[1].rstrip("/"), sys.argv[2]
    operator = open(os.environ["PAGE_OPERATOR_TOKEN_FILE"]).read().strip()
    client = open(os.environ["PAGE_CLIENT_TOKEN_FILE"]).read().strip()
    with tempfile.TemporaryDirectory() as profile:
        b = Browser("/usr/bin/chromium", "/usr/bin/chromedriver", profile)
        try:
            # 1. No session: the login form, nothing of the run.
            b.go(url + "/")
            b.one("#token")
            assert not b.all("#prototype") and not b.all("#live"), "run data shown before login"
            assert post(url + "/live", {})[0] == 405, "GET only"
            # 2. An unknown token.
            login(b, url + "/", "coadapt-" + "0" * 64)
            wait_text(b, "#flash", "not accepted")
            # 3. The client token: the proposal, no buttons.
            login(b, url + "/", client)
            wait_text(b, "#prototype h2", "Build design 1")
            assert "View only" in b.text("#prototype"), b.text("#prototype")
            assert not b.all("#prototype button") and not b.all("#prototype input"), "a view-only session got controls"
            client_cookie = b.cookie("coadapt_session")
            assert client_cookie and client_cookie.get("httpOnly") and client_cookie.get("sameSite") == "Strict", client_cookie
            assert client_cookie.get("secure") == url.startswith("https://"), client_cookie
            client_csrf = call("GET", f"{b.s}/element/{b.one('.who input[name=csrf]')}/property/value")
            # 4. Forged POSTs.
            answer = {"action": "confirm", "index": "0", "proposal": "1"}
            status, body = post(url + "/act", answer)
            assert status == 403 and "no session" in body, (status, body)
            status, body = post(url + "/act", dict(answer, csrf=client_csrf), f"coadapt_session={client_cookie['value']}")
            assert status == 403 and "role client" in body, (status, body)
            b.click(".who button")  # log out
            b.one("#token")
            # 5. The operator: as built, from the page.
            login(b, url + "/", operator)
            wait_text(b, "#prototype h2", "Build design 1")
            assert b.all("#confirm") and b.all("#as-built"), "an operator got no buttons"
            assert not b.all("#reject"), "a fixed initial design offered for rejection"
            op_cookie = b.cookie("coadapt_session")["value"]
            status, body = post(url + "/act", answer, f"coadapt_session={op_cookie}")
            assert status == 403 and "csrf" in body, (status, body)
            for i, v in AS_BUILT.items():
                b.type(f"#as-built-{i}", v, clear=True)
            b.click("#as-built")
            wait_text(b, "#flash", "built as back thigh 1.050")
            # The page moves on by itself (its script) once the run asks for design 2.
            wait_text(b, "#prototype h2", "Build design 2", wait=120)
            b.screenshot(shot)
        finally:
            b.close()
    print(json.dumps({"as_built": {str(k): v for k, v in AS_BUILT.items()}}))


if __name__ == "__main__":
    main()
