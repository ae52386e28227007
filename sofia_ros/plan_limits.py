"""The ranges of a campaign plan's numbers, shared by the plan files (sim.sequence.check_plan_limits) and
`sofia run`'s options: a value outside is refused before the run, not found out in its middle (a hold of 1e300 s
overflowed the clock into a traceback and a half-written bag). No imports: `sofia`'s parser reads it at start-up."""

__all__ = ['MAX_ELEMENT_S', 'MAX_OBSERVATION_OFFSET_S', 'PLAN_LIMITS']

#: The longest hold or temperature element, s (`sofia run --hold-s`'s limit too).
MAX_ELEMENT_S = 7200.0
#: The latest start of a star-hop observation after Table D.3's first, s: a night.
MAX_OBSERVATION_OFFSET_S = 86400.0
#: Each plan field's range: (low, high, unit), both bounds inclusive but a float's low of 0.
PLAN_LIMITS = {
    'repetitions': (2, 100, 'maneuvers per axis'),
    'verification_repetitions': (1, 100, 'maneuvers per axis'),
    'frames_per_position': (1, 100, 'frames'),
    'max_iterations': (1, 20, 'iterations'),
    'drift_track_s': (1.0, 3600.0, 's'),
    'timeout_s': (0.0, 3600.0, 's'),
    'hold_s': (0.0, MAX_ELEMENT_S, 's'),
}
