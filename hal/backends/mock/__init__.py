"""The mock backend: a simulated machine (axes with end stops, wired pins, a DC bridge)
whose every edge goes to a timeline; the daemon's embedded default."""
