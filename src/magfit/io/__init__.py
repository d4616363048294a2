"""Reading magnetometer samples from files and writing calibrated copies of them.

>>> from magfit.io import read_samples          # doctest: +SKIP
>>> table = read_samples("flight.csv")          # doctest: +SKIP
>>> table.samples.shape, table.columns          # doctest: +SKIP
((26407, 3), ('mx', 'my', 'mz'))

Text files (any common delimiter, header or not, preamble lines, UTF-8 BOM, extra columns), ``.npy`` and
``.npz`` are accepted; docs/file-formats.md describes how the magnetometer columns are found (the usual
converters' names too: blackbox_decode, ulog2csv, mavlogdump, ROS CSV, with their unit) and every error. A
file that interleaves several compasses (an ``I`` or ``device_id`` column) is read one at a time,
``read_samples(path, sensor="I=1")``. Reading text needs pandas (the ``cli`` extra); ``import magfit`` does
not import this package.
"""

from __future__ import annotations

from .atomic import STDOUT, atomic_open, atomic_write_text, check_output, write_all
from .columns import ColumnTriple, find_magnetometer_columns
from .readers import ChunkReader, FileFormat, SampleTable, iter_sample_chunks, read_samples, sniff
from .writers import write_calibrated

__all__ = [
    "STDOUT",
    "ChunkReader",
    "ColumnTriple",
    "FileFormat",
    "SampleTable",
    "atomic_open",
    "atomic_write_text",
    "check_output",
    "find_magnetometer_columns",
    "iter_sample_chunks",
    "read_samples",
    "sniff",
    "write_all",
    "write_calibrated",
]
