"""The engine is headless: importing it loads no Qt and no napari."""

import subprocess
import sys


def test_core_imports_no_qt_or_napari():
    code = (
        "import sys, napari_edgecme, napari_edgecme.core, napari_edgecme.core.operators;"
        "import napari_edgecme.cli;"
        "bad = [m for m in sys.modules if m.split('.')[0] in "
        "('qtpy', 'PyQt5', 'PyQt6', 'PySide2', 'PySide6', 'napari', 'magicgui', 'vispy')];"
        "print(bad); sys.exit(1 if bad else 0)"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert res.returncode == 0, res.stdout + res.stderr
