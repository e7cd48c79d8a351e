"""Welch's unequal-variance t-test from the summary statistics the reports keep (mean, population std, seeds).

The same test as ``scipy.stats.ttest_ind(a, b, equal_var=False)`` on the seeds' scores (tested against it): the
standard error of the difference of means from the seeds' sample variances, the Welch-Satterthwaite degrees of
freedom, and the two-sided p-value of Student's t at those degrees of freedom.
"""

from __future__ import annotations

import numpy as np
from scipy import stats


def welch(a: dict, b: dict) -> dict:
    """``a`` against ``b``, each ``{"mean", "std" (population, ddof 0), "n_seeds"}`` with ``n_seeds`` >= 2:
    ``{"diff": a's mean - b's, "se", "df", "p"}``. ``df`` and ``p`` are ``None`` where both columns have no spread
    (``se`` = 0: the test is undefined)."""
    va, vb = (x["std"] ** 2 / (x["n_seeds"] - 1) for x in (a, b))  # the sample variance over n, s^2 / n
    se = float(np.sqrt(va + vb))
    diff = a["mean"] - b["mean"]
    if se == 0.0:
        return {"diff": diff, "se": se, "df": None, "p": None}
    df = (va + vb) ** 2 / (va ** 2 / (a["n_seeds"] - 1) + vb ** 2 / (b["n_seeds"] - 1))
    return {"diff": diff, "se": se, "df": float(df), "p": float(2 * stats.t.sf(abs(diff) / se, df))}
