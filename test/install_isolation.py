"""Run an installed sofia_ros (a wheel's target dir, a colcon install) with the checkout's editable install out of the way.

The test venv holds this checkout as an editable install: a meta-path finder (from a .pth file)
that maps ``sofia_ros`` and its subpackages to the checkout. It would find any module the
install under test lacks. ``isolated_env`` puts a ``sitecustomize`` first on PYTHONPATH that
removes that finder after the .pth files ran, so only the install under test can answer.
"""

from __future__ import annotations

import os
from pathlib import Path

SITECUSTOMIZE = '''\
import sys
sys.meta_path[:] = [finder for finder in sys.meta_path
                    if not getattr(finder, '__module__', '').startswith('__editable__')]
'''


def isolated_env(folder: Path, site_packages: Path) -> dict[str, str]:
    """Environment whose Python finds sofia_ros only in ``site_packages`` (a sitecustomize goes into ``folder``)."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / 'sitecustomize.py').write_text(SITECUSTOMIZE)
    env = {key: value for key, value in os.environ.items() if key != 'PYTHONPATH'}
    env['PYTHONPATH'] = os.pathsep.join([str(folder), str(site_packages)])
    return env
