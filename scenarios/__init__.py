"""The shipped scenarios (``*.yaml`` beside this file), package data of the wheel so that a
``pip install`` can name them: ``formation sim thesis-5.2.2``; ``formation scenarios`` lists them.
Nothing to import here: :mod:`scenario.shipped` finds the files."""
