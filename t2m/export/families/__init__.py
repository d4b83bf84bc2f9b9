"""One exporter per model family (modules -> graphs -> verified bundle), and each family's tiny random bundle
for tests."""
