"""Shared helpers every room of the core uses: typed errors, array helpers, the one atomic write,
nesting-limited JSON, PNG writing, colour conversions and the overlay's colour ramp, stop signals.
Imports nothing else of the core."""
