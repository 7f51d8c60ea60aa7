"""The dashboard's panels; each owns its viser handles and has an ``update`` called by the loop."""
