"""Measurement sets: reduced observables from real logs, compared with a model like a bag (docs/measurement-sets.md).

format (records, kinds and what each sees), validate (YAML -> MeasurementSet, one-line ConfigErrors),
predict (the simulator's physics per row), compare (fit, ledger, ranking, verdict), report (table, HTML).
"""
