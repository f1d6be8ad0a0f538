"""The XRCE agent: asyncio transport servers, the protocol engine and middleware backends (CPython)."""
