"""Diagnosis: which physical effect does a model lack? One engine (``engine``), one adapter per
domain (``encoder``, ``robot``), campaigns in (``campaign``), the PDF out (``report``)."""
