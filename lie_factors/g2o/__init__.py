"""g2o files: find, check, read and write them (the formats have one home here).

* :func:`resolve_dataset` — a path, or the name of a file shipped with GTSAM
  (:mod:`.dataset`);
* :func:`check_g2o` — our own check of every line, so a bad file gives
  ``file:line: what was expected`` instead of GTSAM silently skipping lines or
  reading garbage (:mod:`.check`); the bytes become typed arrays by a numba
  scan (:mod:`.scan`, numbers by :mod:`.strtod`) or, for small files in a
  process without numba, by numpy (lines grouped by tag) (:mod:`.parse`);
* :func:`read_pose_graph` — a file as one :class:`~lie_factors.posegraph.graph.PoseGraph`
  (resolved, checked, read; landmarks as GTSAM's factors) (:mod:`.load`);
* :func:`read_with_gtsam` — ``gtsam.readG2o`` on a checked file, plus the records
  GTSAM's reader skips (``LANDMARK2``, Sim(3)) as GTSAM-native factors;
  :func:`read_arrays` — a pose graph as arrays, no GTSAM object (:mod:`.read`);
* :func:`write_g2o` — ``gtsam.writeG2o`` (+ the landmark records it drops, or
  Sim(3) records), atomically (:mod:`.write`).

The records are the table :data:`RECORDS` (:mod:`.records`): one
:class:`Record` per tag, naming its integer and real fields and the vectorized
check of its rows.  How a record's numbers become GTSAM's elements,
information matrices and keys (and the Sim(3) derivation) is
:mod:`.conventions`.

Imports inside the package point one way: ``records`` → ``strtod`` → ``scan``
→ ``parse`` (with ``dataset``) → ``check`` → ``read``; ``records`` →
``conventions`` → ``read``, ``write``.  The check of a file under
:data:`~lie_factors.g2o.parse.SCAN_MIN_BYTES` in a process that has not loaded
numba imports no numba (the scan is imported only where it pays), and
:mod:`lie_factors.sim3` is imported only when a Sim(3) record is converted.
"""

from __future__ import annotations

from ..errors import InputError
from .check import G2oSummary, check_g2o
from .conventions import (bearing_range_information_2d, landmark_key, point_information_2d, similarity3_from_g2o, similarity3_to_g2o)
from .dataset import resolve_dataset
from .load import read_pose_graph
from .read import arrays_supported, landmark2_factors, read_arrays, read_with_gtsam, read_sim3_g2o
from .records import (INFO_REL_EIG, LANDMARK_ISO_TOL, MAX_ID, RECORDS, SIM3_MAX_LOG_SCALE, Record, Rows, register)
from .write import write_g2o, write_sim3_g2o

__all__ = [
    "InputError", "G2oSummary", "check_g2o", "resolve_dataset",
    "read_pose_graph", "read_with_gtsam", "read_arrays", "arrays_supported", "read_sim3_g2o", "landmark2_factors",
    "write_g2o", "write_sim3_g2o",
    "landmark_key", "bearing_range_information_2d", "point_information_2d",
    "similarity3_from_g2o", "similarity3_to_g2o",
    "RECORDS", "Record", "Rows", "register",
    "INFO_REL_EIG", "LANDMARK_ISO_TOL", "MAX_ID", "SIM3_MAX_LOG_SCALE",
]
