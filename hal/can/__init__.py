"""Everything CAN: MIT-style motors over python-can. `frames` (the codec, the C one's twin in
`c/`), `dialects` (mit, damiao, cubemars: reply layouts, ids, status and registers), `motors`
(data sheets and default ranges), `spec` (the bus described for the configuration and the
validator), `link` (one python-can bus, its errors named), `backend` (`CanBus`) and `bringup`."""
