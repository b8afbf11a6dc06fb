"""Plain Python copies of results for ``json.dumps``."""

from __future__ import annotations

from pathlib import PurePath
from typing import Any

import numpy as np

__all__ = ["plain_json"]


def plain_json(value: Any) -> Any:
    """``value`` with numpy scalars and arrays turned into plain Python (for ``json.dumps``).

    Dictionaries get string keys, tuples become lists, paths become strings,
    and non-finite floats become ``None`` (JSON has no NaN).

    Examples
    --------
    >>> import numpy as np
    >>> plain_json({"a": np.arange(2), 1: (np.float64("nan"), np.bool_(True))})
    {'a': [0, 1], '1': [None, True]}
    """
    if isinstance(value, dict):
        return {str(k): plain_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain_json(v) for v in value]
    if isinstance(value, np.ndarray):
        return plain_json(value.tolist())
    if isinstance(value, PurePath):
        return str(value)
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if np.isfinite(value) else None
    return value
