"""The thesis-table reproductions behind ``prismstereo reproduce`` (one module per table)."""
