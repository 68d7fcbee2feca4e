"""Local matchers: pixel costs, aggregation (box, guided, BPASW adaptive weights), disparity selection, and the
``sad``/``bpasw``/``sgbm``/``sgm`` matchers built on them."""
