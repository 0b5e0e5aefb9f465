"""numpy oracles for tests and benchmarks; not shipped in the extension."""
