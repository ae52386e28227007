"""The records of `sofia compare --json`, typed (docs/compare.md; the whole document: docs/schemas/compare.schema.json).

A bag and a measurement set write the same records (compare.pipeline); keys only one source writes are in the
``total=False`` bases. The test suite checks every document it writes against these and the schema.
"""

from __future__ import annotations

from typing import TypedDict

__all__ = ['CandidateEntry', 'ConsistencyFinding', 'LedgerRow', 'NextStep', 'ObservableJudgement', 'Verdict']


class _CandidateOptional(TypedDict, total=False):
    #: why the source cannot see it (a measurement set's kinds, or absorbed by a fitted term)
    reason: str | None
    #: a rate-only set's RMS with the candidate ["/s]
    rms_after_arcsec_per_s: float | None


class CandidateEntry(_CandidateOptional):
    """One candidate effect fitted with the model (compare.pipeline.candidate_entry)."""

    effect: str
    rms_after_arcsec: float | None
    delta_bic: float
    params: dict[str, float]
    sigma: dict[str, float | None]
    units: dict[str, str]
    detectable: bool
    refined: bool
    seconds: float
    empirical: bool
    observable: str | None
    variable: str | None
    period_s: float | None


class _LedgerRowOptional(TypedDict, total=False):
    #: a set's rate RMS per observable ["/s]
    residual_rms_arcsec_per_s: dict[str, float]


class LedgerRow(_LedgerRowOptional):
    """One step of the ledger: a fitted term switched on, the RMS and BIC after it."""

    term: str
    residual_rms_arcsec: dict[str, float]
    bic: float


class _ObservableOptional(TypedDict, total=False):
    #: an angle's RMS and floor ["], or a rate's (a set's earth_rate tables) ["/s]
    rms_arcsec: float
    floor_arcsec: float
    rms_arcsec_per_s: float
    floor_arcsec_per_s: float
    #: a bag's excess over the floor in sigmas, and whether the observable is a camera or gyro axis
    excess_sigma: float | None
    kind: str
    #: a set's rows of the observable
    rows: int


class ObservableJudgement(_ObservableOptional):
    """One observable against its floor (compare.verdict.judge): an angle's RMS in arcsec or a rate's in arcsec/s."""

    ratio: float
    explained: bool
    structure: list[str]


class NextStep(TypedDict):
    """The one thing to do next (compare.verdict.next_step)."""

    action: str
    effect: str | None
    term: str | None
    command: str | None


class Verdict(TypedDict):
    """The verdict: status, a headline of at most 100 characters, the reasons, every observable, the next step."""

    status: str
    headline: str
    text: str
    observables: dict[str, ObservableJudgement]
    next: NextStep
    inconsistent_terms: list[str]
    after_best: dict | None


class ConsistencyFinding(TypedDict):
    """A fitted term that changes between halves of the data (compare.diagnostics.split_consistency)."""

    param: str
    split: str
    halves: list[str]
    values: list[float]
    sigmas: list[float]
    significance_sigma: float
