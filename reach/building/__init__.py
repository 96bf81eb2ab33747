"""Building maps: a VATree refined by an oracle, the atlas of a config's strategies, the executors that run the
oracle, the index's and the mirror's derivation."""
