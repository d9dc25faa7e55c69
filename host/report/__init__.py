"""Reports of what servodyn ran: a run's table and tracking figure (`swing`), a motion's validation
report and figures (`validation`), and the plots they draw (`plots`). Above the loop and the
simulator, below the commands."""
