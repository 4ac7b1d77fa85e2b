"""Analysis of recorded runs: ``sappc report`` and ``compare`` (``report``), the figures
(``plots``) and ``sappc rerun`` (``rerun``)."""
