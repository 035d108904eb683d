"""How far a result lies from a reference and what it costs: accuracy measures, the
radar noise floor as a power budget, the speed-accuracy trade-off. It may import every
other layer; nothing in the package imports it."""
