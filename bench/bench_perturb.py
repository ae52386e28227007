"""Benchmark: `sofia perturb` on a full-size alignment-campaign bag, a camera axis and a gyro axis.

The bag is the default campaign of `scripts/run-main` (nominal truth, seed 1, 6 repetitions,
direct mode), made in a temporary directory unless a bag is given. Printed: wall time of
perturb_bag (reading the variables, evaluating the shape, writing the copy), the better of two
runs, for an FPI column step (every chunk holds centroids, so every chunk is recompressed) and for
a specific-force shape on the LOS gyro (every Imu sample re-packed). Targets: a few seconds for the
camera, well under a minute for the gyro, on the 2-core machine.

Run: .venv/bin/python bench/bench_perturb.py [BAG]
"""

from __future__ import annotations

import shutil
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from sofia_ros.bag import BagReader  # noqa: E402
from sofia_ros.campaigns.alignment import run_alignment  # noqa: E402
from sofia_ros.config import load_effect_config  # noqa: E402
from sofia_ros.perturb import perturb_bag  # noqa: E402

from results_file import Transcript, current_load, write_results  # noqa: E402

#: Every line printed, for bench/results/perturb.txt.
TRANSCRIPT = Transcript()
say = TRANSCRIPT.say

CASES = (('fpi.x', '2.0*(time_s > 600)'), ('gyro.los', '0.5*specific_force_z_m_per_s2/9.81'))


def main():
    load_before = current_load()
    document = {'bag': sys.argv[1] if len(sys.argv) > 1 else None, 'cases': []}
    with tempfile.TemporaryDirectory(prefix='bench_perturb_') as folder:
        if len(sys.argv) > 1:
            bag = Path(sys.argv[1])
        else:
            bag = Path(folder) / 'alignment'
            started = time.perf_counter()
            run_alignment(load_effect_config(ROOT / 'config/truth/nominal.yaml'), seed=1, bag_path=bag, mode='direct')
            document['record_s'] = time.perf_counter() - started
            say(f'campaign (direct mode) recorded in {document["record_s"]:.1f} s: {bag}')
        with BagReader(bag) as reader:
            counts = {info.name: info.count for info in reader.topics}
        size_mb = sum(path.stat().st_size for path in bag.glob('*.mcap')) / 1e6
        document.update(bag_mb=size_mb, messages=sum(counts.values()), imu_samples=counts['/gyro_box/imu'])
        say(f'bag: {size_mb:.1f} MB, {sum(counts.values())} messages, {counts["/gyro_box/imu"]} Imu samples')
        for observable, shape in CASES:
            best_s = float('inf')
            for attempt in range(2):
                out = Path(folder) / f'perturbed-{attempt}'
                started = time.perf_counter()
                result = perturb_bag(bag, out, observable, shape)
                best_s = min(best_s, time.perf_counter() - started)
                shutil.rmtree(out)
            say(f'{observable:<9} {shape!r:<40} {best_s:6.2f} s wall, {result.rows_changed} rows changed, '
                f'RMS {result.rms:.4g} {result.unit}')
            document['cases'].append({'observable': observable, 'shape': shape, 'best_wall_s': best_s,
                                      'rows_changed': result.rows_changed, 'rms': result.rms, 'unit': result.unit})
    write_results('perturb', document, TRANSCRIPT.lines, load_before=load_before)


if __name__ == '__main__':
    main()
