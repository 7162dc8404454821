r"""The history store: every unit's calibration records, indexed in SQLite, each record verified when it is read.

Layout of a store (``--store DIR``, default ``$STABLEINS_HISTORY`` or ``~/.local/share/stableins/history``)::

    DIR/history.sqlite                       the index (SQLite, WAL mode): units, records, digests, statuses
    DIR/<serial>/<valid-from>-<sha8>.json    the records, copied in byte for byte
    DIR/<serial>/<valid-from>-<sha8>.evidence.json   the data-only estimate a recalibration kept beside its record
                                                     (stores of earlier versions; records now carry their likelihoods)

Why a database (docs/procedures.md, README "Dependencies and why"): the index is changed in transactions, so any
number of processes may file records at once (``stableins history --add``, ``stableins recal``) without losing an
entry, and a process killed at any moment (``kill -9``, power loss) leaves it as it was before or after its
transaction, never in between.  Writers take SQLite's write lock for the whole of a filing (``BEGIN IMMEDIATE``:
they queue, with a busy timeout of :data:`BUSY_TIMEOUT` seconds); readers never block them (WAL).  A filing
writes the record's file before the transaction that indexes it commits, so every indexed file exists; a
record file without an index row (a filing killed between the two) is never read and is rewritten, byte for
byte, when the record is filed again.

The index holds, per record: the unit, the file, its SHA-256, the time it is valid from, its creation time,
procedure, stages, the prior it was built on, every parameter's value, σ and status, and the data-only estimates
of its calibration (:func:`stableins.history.data_only`, the points of the drift), so that a laboratory can ask
about its whole fleet without opening a record: which units are due (:meth:`HistoryStore.fleet`, ``stableins
history --fleet --due``), which drift (``--drifted``).  A record is read only through :meth:`HistoryStore.load`,
which compares its SHA-256 with the index and refuses a record changed after it was filed, naming its path and
the digest expected.

Stores written by earlier versions (``DIR/<serial>/index.json``) are migrated on first use: each unit's entries
are checked against their files' digests and indexed in one transaction; the old index is then renamed
``index.json.migrated``.

The package's public API is the names below (``from stableins.history_store import HistoryStore``); its
modules, by concern: :mod:`~stableins.history_store.schema` (the index's schema, rows, transactions, format
check), :mod:`~stableins.history_store.filing` (reading, staging and indexing the files filed),
:mod:`~stableins.history_store.legacy` (migration of the JSON stores), :mod:`~stableins.history_store.queries`
(fleet questions from the index alone), :mod:`~stableins.history_store.store` (:class:`HistoryStore`).
"""

from stableins.history_store.legacy import INDEX_FORMAT, INDEX_NAME
from stableins.history_store.queries import DRIFT_SIGMAS, UnitStatus
from stableins.history_store.schema import (
    BUSY_TIMEOUT,
    MAX_RECORD_BYTES,
    STORE_FORMAT,
    STORE_NAME,
    STORE_SCHEMA_VERSION,
    HistoryEntry,
    default_store,
)
from stableins.history_store.store import HistoryStore

__all__ = [
    "BUSY_TIMEOUT",
    "DRIFT_SIGMAS",
    "INDEX_FORMAT",
    "INDEX_NAME",
    "MAX_RECORD_BYTES",
    "STORE_FORMAT",
    "STORE_NAME",
    "STORE_SCHEMA_VERSION",
    "HistoryEntry",
    "HistoryStore",
    "UnitStatus",
    "default_store",
]
