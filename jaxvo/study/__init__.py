"""Studies over sequences, settings and seeds: ``spec`` (the file, its checks and its
configurations), ``data`` (each sequence's flow and its cache), ``devices`` (processes,
batch, compiled programs, calls), ``runner`` (the runs over every device, scores, resume;
it re-exports the others' public names) and ``report`` (tables and plots)."""
