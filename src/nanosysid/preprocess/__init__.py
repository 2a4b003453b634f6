"""Preprocessing of the extracted tables into flights: one clock and one grid (:mod:`.sync`),
then gap filling and zero-phase filtering (:mod:`.filtering`). Reading and writing the bags
themselves is :mod:`nanosysid.bags`; the settings of the whole chain (extract, sync, filter)
are the ``preprocess`` config group."""
