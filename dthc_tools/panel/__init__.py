"""The operator panel (``dthc-bridge panel``): a web page beside the table, served by its
own process, an MQTT client of the daemon and the sender like any other."""
