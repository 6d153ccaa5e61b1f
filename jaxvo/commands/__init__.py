"""Subcommands of the jaxvo CLI: each module has add_arguments(parser) and run(args).

Keep module-level imports light (no JAX): every module is imported to build --help.
"""
