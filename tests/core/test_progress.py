"""Progress bars fit an 80-column terminal (issue 59): the count and the ETA stay whole,
the description gives way."""

import io

from rich.console import Console
from rich.progress import Progress

from core.progress import columns


def test_a_bar_on_80_columns_keeps_its_count_and_eta_whole():
    for width in (80, 100, 200):
        screen = Console(file=io.StringIO(), width=width, force_terminal=True, color_system=None)
        with Progress(*columns(width), console=screen, auto_refresh=False) as progress:
            task = progress.add_task("evaluate reference_augmented (oracle_box) on the testbed images (local)",
                                     total=1234)
            progress.advance(task, 617)
            progress.refresh()
        text = screen.file.getvalue().replace("\r", "\n")
        last = [line for line in text.splitlines() if "/1234" in line][-1].replace("\x1b[?25h", "").rstrip()
        assert len(last) <= width and "617/1234" in last and "ETA" in last and "…" not in last.split("ETA")[1], last
