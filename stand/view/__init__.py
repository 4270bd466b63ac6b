"""The operator page: a browser view of a run, live (``stand run --view``) or replayed (``stand view RUN_DIR``).

* :mod:`stand.view.state`: what the page shows, from a run folder or from a live run's rows (``LiveFeed``,
  the loop's observer), and the panorama's projection;
* :mod:`stand.view.server`: the aiohttp server on its own thread (``ViewServer``), with pause, resume and stop
  of a live run;
* :mod:`stand.view.export`: the panorama as PNG for reports;
* ``assets/``: the page (HTML, CSS, canvas drawing in ``view.js``) and the land outlines, shipped in the wheel.
"""
