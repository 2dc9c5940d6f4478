"""A pandas DataFrame as a :class:`~piezohyst.data._columns.Source` (DataFrames, Parquet, Excel)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from ._columns import ROLE_WORDS, Key, flag, guess_by_alias, match_name
from ._dataset import DataError
from ._units import normal_name

_INDEX = "<index>"


def _short(items: Sequence[Any], n: int = 12) -> str:
    shown = ", ".join(repr(str(x)) for x in items[:n])
    return f"[{shown}{', ...' if len(items) > n else ''}]"


class FrameSource:
    """Columns of a DataFrame, found by name (with units) or 0-based position."""

    def __init__(self, df: Any, *, where: str, fmt: str = "DataFrame") -> None:
        import pandas as pd

        if not isinstance(df, pd.DataFrame):
            raise DataError(f"{where}: expected a pandas DataFrame, got {type(df).__name__}")
        self.df = df
        self.where = where
        self.meta: dict[str, Any] = {"format": fmt}
        self._names = [(i, [str(c)]) for i, c in enumerate(df.columns)]
        attrs_units = df.attrs.get("units") if isinstance(df.attrs, dict) else None
        self._units = attrs_units if isinstance(attrs_units, dict) else {}

    # -- naming ----------------------------------------------------------------------------------
    def listing(self) -> str:
        return f"the columns are {_short([str(c) for c in self.df.columns])}"

    def find(self, given: Any, role: str) -> Key:
        ncol = self.df.shape[1]
        if isinstance(given, (int, np.integer)) and not isinstance(given, bool):
            if not 0 <= int(given) < ncol:
                raise DataError(f"{self.where}: column {int(given)} does not exist (there are {ncol} columns, "
                                f"numbered from 0); {self.listing()}")
            return int(given)
        if not isinstance(given, str):
            raise DataError(f"{self.where}: a column is named by a string or a 0-based number, got {given!r} "
                            f"({flag(role)})")
        hits = match_name(given, self._names)
        if not hits and role == "t" and self._index_is_time(strict=False) and \
                normal_name(given) == normal_name(str(self.df.index.name or "index")):
            return _INDEX
        if len(hits) > 1:
            raise DataError(f"{self.where}: {given!r} matches several columns ({_short([self.label(h) for h in hits])}); "
                            f"give its 0-based number ({flag(role)})")
        if not hits:
            raise DataError(f"{self.where}: no column {given!r} ({ROLE_WORDS[role]}); {self.listing()}")
        return hits[0]

    def guess(self, role: str) -> Key | None:
        k = guess_by_alias(self._names, role, self.where, describe=self.label)
        if k is None and role == "t" and self._index_is_time(strict=True):
            return _INDEX
        return k

    def _index_is_time(self, *, strict: bool) -> bool:
        import pandas as pd

        idx = self.df.index
        if isinstance(idx, (pd.TimedeltaIndex, pd.DatetimeIndex)):
            return True
        if not pd.api.types.is_numeric_dtype(idx.dtype):
            return False
        if not strict:
            return True
        from ._columns import ALIASES

        return idx.name is not None and normal_name(str(idx.name)) in ALIASES["t"]

    def companion_time(self, key: Key) -> Key | None:
        return None

    def label(self, key: Key) -> str:
        if key == _INDEX:
            return str(self.df.index.name or "index")
        return str(self.df.columns[key])

    def unit_name(self, key: Key) -> str:
        return self.label(key)

    def stated_unit(self, key: Key) -> str | None:
        if key == _INDEX:
            return None
        u = self._units.get(self.df.columns[key], self._units.get(self.label(key)))
        return u if isinstance(u, str) else None

    # -- values ----------------------------------------------------------------------------------
    def read(self, keys: Sequence[Key], limit: int) -> list[np.ndarray]:
        return [self._column(k) for k in keys]

    def _column(self, key: Key) -> np.ndarray:
        import pandas as pd

        if key == _INDEX:
            values: Any = self.df.index
        else:
            values = self.df.iloc[:, key]
        dtype = values.dtype
        if isinstance(values, (pd.TimedeltaIndex, pd.DatetimeIndex)) or pd.api.types.is_datetime64_any_dtype(dtype) \
                or pd.api.types.is_timedelta64_dtype(dtype):
            # clock times or durations: seconds from the first sample
            v = pd.Series(values)
            if v.isna().any():
                i = int(np.argmax(v.isna().to_numpy()))
                raise DataError(f"{self.where}: {self.locate(key, i)} of {self.label(key)!r} has no time")
            delta = v - v.iloc[0]
            return delta.dt.total_seconds().to_numpy(dtype=np.float64, copy=True)
        if pd.api.types.is_bool_dtype(dtype) or pd.api.types.is_complex_dtype(dtype):
            raise DataError(f"{self.where}: column {self.label(key)!r} holds {dtype} values, not real numbers")
        if pd.api.types.is_numeric_dtype(dtype):
            return pd.Series(values).to_numpy(dtype=np.float64, na_value=np.nan, copy=True)
        num = pd.to_numeric(pd.Series(values), errors="coerce")
        bad = num.isna().to_numpy() & pd.Series(values).notna().to_numpy()
        if bad.any():
            i = int(np.argmax(bad))
            raise DataError(f"{self.where}: {self.locate(key, i)}, column {self.label(key)!r} holds "
                            f"{str(pd.Series(values).iloc[i])[:40]!r}, not a number")
        return num.to_numpy(dtype=np.float64, na_value=np.nan, copy=True)

    def locate(self, key: Key, row: int) -> str:
        return f"row {row} (index {self.df.index[row]!r})"

    def explain(self, key: Key, row: int, value: float = math.nan) -> str:
        if key == _INDEX:
            value = self.df.index[row]
        else:
            value = self.df.iloc[row, key]
        return f"{self.locate(key, row)}, column {self.label(key)!r} holds {str(value)!r}, not a finite number"
