"""`tomllib` on every supported Python: the standard library's from 3.11, the same parser as the `tomli`
package on 3.10 (a dependency there only). Import it as `from rodo.estimator.tomlcompat import tomllib`.

Checked by: tests/test_packaging.py::test_toml_reader_on_this_python
"""

from __future__ import annotations

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

__all__ = ["tomllib"]
