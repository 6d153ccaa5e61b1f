"""Studies over sequences, settings and seeds: ``runner`` (spec, flow cache, the runs
over every device, scores, resume) and ``report`` (tables and plots)."""
