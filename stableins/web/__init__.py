"""``stableins serve``: a laboratory's fleet in a browser (docs/fleet.md), read-only.

Modules, by concern: :mod:`~stableins.web.policy` (when a unit is due), :mod:`~stableins.web.certificates` (the
certificates and technical reports under the run root, by the SHA-256 of the record they certify),
:mod:`~stableins.web.fleet` (the fleet and a unit's history, from the history store and the same code as
``stableins history``), :mod:`~stableins.web.runs` (runs under the run root and their live progress from the
journal), :mod:`~stableins.web.security` (token, limits, read-only), :mod:`~stableins.web.app` (the FastAPI
application: HTML pages and the JSON API under ``/api`` with OpenAPI).  FastAPI, uvicorn, Jinja2, Plotly and pypdf
come with ``pip install 'stableins[web]'``.
"""
