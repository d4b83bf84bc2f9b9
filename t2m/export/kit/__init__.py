"""What every exporter and importer shares: text sources, training-run records, parity and int8 checks."""
