"""The ``jaxvo`` command line: ``main`` (parser, exit statuses, one-line errors) and one
module per subcommand."""
