"""Many captures: every capture of a manifest fitted (and scored, and reported) as a Ray task.

`run` reads a manifest (a CSV or JSON Lines file, one capture a line with optional settings, or a
folder of captures), checks all of it before any work, and runs each capture's whole job as one
Ray task: the pipeline of docs/method.md#pipeline (`freqbrdf.pipeline.fit`, `write_fit`), the scores of
docs/method.md#evaluation where the capture has ground truth or test views (`freqbrdf.outputs.evaluate`) and
the report (`freqbrdf.outputs.report`), into ``OUT/<name>/``, which appears complete or not at
all. Ray starts on this machine (workers sized to its cores and memory, `default_workers`) or
joins a cluster by its address (docs/batch.md: the head, the worker nodes, the token, and the
captures and output folder at the same paths on every node). A capture whose inputs, settings and freqbrdf version are
unchanged is skipped, so an interrupted batch goes on where it stopped; bad input fails that
capture alone; a worker that dies is retried. ``OUT/batch.json`` and ``OUT/index.html`` hold
every capture's status, seconds, attempts, error, key metrics and paths.

The modules, in the order a capture meets them:

- `settings`: a capture's settings, checked, made into a `Config` and hashed;
- `manifest`: reading and checking a manifest (`read_manifest`, `ManifestEntry`);
- `state`: what a batch keeps in OUT between runs: the inputs' content hashes,
  ``batch_entry.json``, the up-to-date check, the rename into place and the lock;
- `cluster`: how many captures a machine runs at once, starting Ray or joining a cluster;
- `tasks`: the Ray task that makes one capture's outputs;
- `runner`: `run`, the driver: scheduling, retries, interruption and progress;
- `index`: writing batch.json and index.html.
"""

from freqbrdf.batch.cluster import FIT_THREADS, MAX_RETRIES, default_workers, fit_memory
from freqbrdf.batch.index import BATCH_FILE, INDEX_FILE
from freqbrdf.batch.manifest import ManifestEntry, read_manifest
from freqbrdf.batch.runner import STATUSES, BatchInterrupted, run
from freqbrdf.batch.settings import SETTINGS, capture_config, parse_settings, settings_hash
from freqbrdf.batch.state import ENTRY_FILE, WORK_FOLDER

__all__ = [
    "BATCH_FILE", "ENTRY_FILE", "FIT_THREADS", "INDEX_FILE", "MAX_RETRIES", "SETTINGS", "STATUSES", "WORK_FOLDER",
    "BatchInterrupted", "ManifestEntry", "capture_config", "default_workers", "fit_memory", "parse_settings",
    "read_manifest", "run", "settings_hash",
]
