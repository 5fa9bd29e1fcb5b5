"""Foxglove Studio, offline: the pinned app (`app`), a server of the app, layout and logs (`server`), headless
Chromium over the DevTools protocol (`browser`) and what the app shows of a log (`capture`). `python -m flows.view`
is the command."""
