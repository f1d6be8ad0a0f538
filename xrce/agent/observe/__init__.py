"""What a running agent is doing, for its operator: ``observability`` (counters, rates, the stats
port, the periodic log summary), ``stats_view`` (``xrce-agent stats``), ``diagnostics``
(``/diagnostics`` with ``-m dds``) and ``capture`` (``--capture FILE``)."""
