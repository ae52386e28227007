"""Where a benchmark leaves its figures: bench/results/<name>.json and .txt, dated, with commit, machine and load.

A bench prints through a ``Transcript`` (every line also kept) and ends with ``write_results``: the
JSON holds the figures it computed, the text file every line it printed under one header line. Both
are written whole or not at all (sofia_ros.output_files: temporary file in bench/results/, rename).
Benches run as ``python bench/bench_x.py`` import this as ``results_file`` (bench/ is sys.path[0]).
"""

from __future__ import annotations

import datetime as dt
import json
import os
import platform
import subprocess
from pathlib import Path

from sofia_ros.output_files import json_ready, write_text_atomically

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / 'bench' / 'results'


class Transcript:
    """Prints each line at once (a long bench shows its progress) and keeps it for the results .txt."""

    def __init__(self) -> None:
        self.lines: list[str] = []

    def say(self, line: str = '') -> None:
        """Print ``line`` and record it."""
        print(line, flush=True)
        self.lines.append(line)


def machine_description() -> str:
    """The machine as a result records it: architecture, processor model and whether it has AVX-512, cores.

    The processor is named because a nearly degenerate fit can end elsewhere on other SIMD kernels (2026-11-29:
    the 2004 short moves' delta-BIC was 6 on one processor and 11 on an AMD EPYC without AVX-512).
    """
    model, avx512 = 'processor unknown', False
    try:
        for line in Path('/proc/cpuinfo').read_text().splitlines():
            if line.startswith('model name') and model == 'processor unknown':
                model = line.split(':', 1)[1].strip()
            elif line.startswith('flags'):
                avx512 = 'avx512f' in line.split()
                break
    except OSError:
        pass
    return f'{platform.machine()}, {model}{", AVX-512" if avx512 else ", no AVX-512"}, {os.cpu_count()} cores'


def current_load() -> float:
    """The 1-minute load average: every figure of a shared machine is read beside it."""
    return os.getloadavg()[0]


def _commit() -> str:
    """The checkout's short commit, or 'unknown' outside a git checkout."""
    process = subprocess.run(['git', 'rev-parse', '--short', 'HEAD'], cwd=ROOT, capture_output=True, text=True,
                             check=False)
    return process.stdout.strip() or 'unknown'


def write_results(name: str, document: dict, lines: list[str], *, load_before: float | None = None,
                  load_after: float | None = None) -> Path:
    """Write bench/results/<name>.json (``document`` plus date, commit, machine, load) and <name>.txt.

    Args:
        name: the bench's name, e.g. 'allan' for bench/bench_allan.py.
        document: the figures the bench computed (numpy scalars and non-finite floats are made strict JSON).
        lines: every line the bench printed, in order.
        load_before: the 1-minute load average when the bench started, if it read one.
        load_after: the load when it ended; read now when not given.

    Returns:
        The path of the JSON file.
    """
    stamp = {'date': dt.datetime.now(dt.timezone.utc).isoformat(timespec='seconds'), 'commit': _commit(),
             'machine': machine_description()}
    if load_before is not None:
        stamp['load_before'] = load_before
    stamp['load_after'] = current_load() if load_after is None else load_after
    load = ', '.join(f'{key.replace("_", " ")} {stamp[key]:.1f}' for key in ('load_before', 'load_after')
                     if key in stamp)
    RESULTS.mkdir(exist_ok=True)
    json_path = RESULTS / f'{name}.json'
    write_text_atomically(json_path, json.dumps(json_ready({**stamp, **document}), indent=1) + '\n')
    header = f'{stamp["date"]} commit {stamp["commit"]}, {stamp["machine"]}, {load}'
    write_text_atomically(RESULTS / f'{name}.txt', '\n'.join([header, *lines]) + '\n')
    return json_path
