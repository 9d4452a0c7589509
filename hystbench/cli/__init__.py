"""The command line: ``main`` builds the parser; one module per command group registers its
subcommands and turns user errors into one-line messages.  No library code lives here, and nothing
imports this package."""
