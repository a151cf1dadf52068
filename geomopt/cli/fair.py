"""``geomopt fair``: a triangle surface smoothed by one of the lectures' methods
(:func:`geomopt.fairing.fair`) and written, as an OBJ with the same faces, only when no face is
folded (exact certificate)."""

from __future__ import annotations

from .common import EXIT_OK, cache_summary, fail, log, output_paths, report

__all__ = ["cmd_fair"]


def _options(args):
    """The :class:`~geomopt.fairing.FairOptions` of the command line."""
    from ..fairing import FairOptions

    given = {name: getattr(args, name) for name in ("laplacian", "steps", "lam", "mu", "time", "weight",
                                                   "eigenvectors", "crease_angle") if getattr(args, name) is not None}
    return FairOptions(method=args.method, boundary=args.boundary, preserve_volume=args.preserve_volume, **given)


def cmd_fair(args) -> int:
    """Smooth a triangle surface (:func:`geomopt.fairing.fair`) into a certified OBJ."""
    from .. import io
    from ..fairing import fair

    split = args.timing
    split.mark_imported()
    options = _options(args)  # bad values: a ParameterError (exit 2) before any work
    output_paths(args.output, (".obj",), (), [args.input])
    with split.phase("read"):
        V, F = io.read_mesh(args.input)
    with split.phase("solve"):
        res = fair(V, F, options=options)
    d = res.details
    log(args, f"{args.input}: {len(V)} vertices, {len(F)} faces; {options.method} ({d.options.laplacian} "
              f"Laplacian): {d.message}; {res.certificate.message}; {res.stats.seconds:.2f} s")
    report(args, input=str(args.input), output=str(args.output), vertices=len(V), faces=len(F),
           method=options.method, laplacian=d.options.laplacian, folded_before=d.folded_before,
           folded_after=res.certificate.inverted, folds_added=d.folds_added, cut=d.cut, removal_rounds=d.removal_rounds,
           min_angle_before=d.min_angle_before, min_angle_after=d.min_angle_after,
           volume_before=d.volume_before, volume_after=d.volume_after, outcome=res.outcome.value,
           solve_seconds=round(res.stats.seconds, 4), message=d.message, **cache_summary())
    if not res.success:
        return fail(f"not certified: {res.reason}")
    with split.phase("write"):
        io.write_obj(args.output, res.x, F)
    return EXIT_OK
