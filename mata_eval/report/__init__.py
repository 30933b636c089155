"""Reports of scored runs: tables, plots, the paper's tables, the HTML summary and timelines."""
