"""Runtime plumbing under every layer: errors, argument checks, 64-bit mode, tracing guards,
the compilation cache and kept programs, host callbacks, timing, padding, options objects,
and the built-in names table.  Nothing here imports
from the rest of geomopt."""
