"""report.html in a real browser: no horizontal overflow, no word broken across lines.

Headless Chromium lays the tiny run's report out at 1280 and 800 px wide; a
script injected into a copy of the page measures it: the document's width
against the viewport's, and for every word (whitespace-separated) of the table
cells, headings, definition lists, cards and notes, whether the word goes onto
another line anywhere but right after a hyphen (a path's ``<wbr>`` after ``/``
or ``_`` splits it into separate words). Skipped where no Chromium is installed
(``.ci/run`` installs it).
"""

from __future__ import annotations

import html
import json
import re
import shutil
import subprocess
from pathlib import Path

import pytest

#: Viewport widths checked (a laptop's browser window, a narrow one).
WIDTHS = (1280, 800)


def _chromium() -> str | None:
    if Path("/usr/bin/chromium").is_file():
        return "/usr/bin/chromium"
    return shutil.which("chromium") or shutil.which("chromium-browser")


CHROMIUM = _chromium()

pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="needs chromium (headless)")

#: Runs after the page and its images have loaded; writes its verdict as JSON
#: into <pre id="bm-check">, which --dump-dom prints.
CHECK_SCRIPT = """
<script>
window.addEventListener("load", function () {
  var root = document.documentElement;
  var out = {width: root.clientWidth, scrollWidth: root.scrollWidth, words: 0, broken: []};
  var scope = "td, th, dt, dd, h1, h2, h3, .card, p, li, figcaption";
  function rectsOf(node, start, end) {
    var range = document.createRange();
    range.setStart(node, start);
    range.setEnd(node, end);
    return Array.prototype.filter.call(range.getClientRects(), function (r) {
      return r.width > 0 && r.height > 0;
    });
  }
  var walker = document.createTreeWalker(document.body, NodeFilter.SHOW_TEXT);
  var node;
  while ((node = walker.nextNode())) {
    var parent = node.parentElement;
    if (!parent || !parent.closest(scope) || parent.closest("script, style")) continue;
    var re = /\\S+/g, m;
    while ((m = re.exec(node.data))) {
      out.words += 1;
      var rects = rectsOf(node, m.index, m.index + m[0].length);
      var multiline = rects.some(function (r) {
        return Math.abs(r.top - rects[0].top) > rects[0].height / 2;
      });
      if (!multiline) continue;
      // Where the word goes onto a new line: only after a hyphen is allowed.
      var top = rects[0].top, half = rects[0].height / 2;
      for (var k = 1; k < m[0].length; k++) {
        var c = rectsOf(node, m.index + k, m.index + k + 1);
        if (!c.length || Math.abs(c[0].top - top) <= half) continue;
        top = c[0].top;
        if (m[0].charAt(k - 1) !== "-") {
          out.broken.push({word: m[0], at: k, in: parent.tagName.toLowerCase(),
                           text: (parent.textContent || "").trim().slice(0, 80)});
          break;
        }
      }
    }
  }
  var pre = document.createElement("pre");
  pre.id = "bm-check";
  pre.textContent = JSON.stringify(out);
  document.body.appendChild(pre);
});
</script>
"""


def _layout(page: Path, width: int, profile: Path) -> dict:
    """Open ``page`` in headless Chromium ``width`` px wide; the check script's verdict."""
    assert CHROMIUM is not None
    command = [
        CHROMIUM,
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--hide-scrollbars",
        f"--user-data-dir={profile}",
        f"--window-size={width},1000",
        "--virtual-time-budget=5000",
        "--dump-dom",
        page.as_uri(),
    ]
    done = subprocess.run(command, capture_output=True, text=True, timeout=60, check=False)
    found = re.search(r'<pre id="bm-check">(.*?)</pre>', done.stdout, re.S)
    if found is None:
        pytest.fail(f"chromium printed no verdict (exit {done.returncode}): {done.stderr[-2000:]}")
    return json.loads(html.unescape(found.group(1)))


def test_report_has_no_broken_words_and_no_overflow(review_run, tmp_path):
    source = (review_run.folder / "report.html").read_text()
    assert source.count("</body>") == 1
    page = tmp_path / "report.html"
    page.write_text(source.replace("</body>", CHECK_SCRIPT + "</body>"))
    for width in WIDTHS:
        verdict = _layout(page, width, tmp_path / f"profile-{width}")
        assert width - 20 <= verdict["width"] <= width, verdict  # the viewport asked for
        assert verdict["words"] > 500, verdict  # the check saw the page
        assert verdict["scrollWidth"] <= verdict["width"], f"{width} px: overflows: {verdict}"
        assert verdict["broken"] == [], f"{width} px: words broken: {verdict['broken'][:10]}"
