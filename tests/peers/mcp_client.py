"""An MCP client nobody here wrote (the `mcp` package from PyPI) against `ferrosa mcp`.

    mcp_client.py stdio FERROSA [ARGS...]   # one server process per session
    mcp_client.py http URL                  # every session against one server
                                            # (the server's secret in FERROSA_MCP_TOKEN)

Three sessions, each: initialize, list the tools, call ros_node_list, then ask
turtle_move to drive 0.5 m. The first session's client cannot elicit; the second
approves the move when asked; the third declines. Prints one JSON object with what
each session saw, for the Rust test to judge.
"""

import asyncio
import json
import os
import sys

import mcp.types as types
from mcp import ClientSession, StdioServerParameters, stdio_client
from mcp.client.streamable_http import streamable_http_client
from mcp.shared._httpx_utils import create_mcp_http_client

ASKED = []


async def approve(context, params):
    ASKED.append(params.message)
    return types.ElicitResult(action="accept", content={"approve": True})


async def decline(context, params):
    ASKED.append(params.message)
    return types.ElicitResult(action="decline")


def text_of(result):
    return "".join(c.text for c in result.content if getattr(c, "type", "") == "text")


async def session(streams, elicit):
    read, write = streams
    kwargs = {"elicitation_callback": elicit} if elicit else {}
    async with ClientSession(read, write, **kwargs) as s:
        await s.initialize()
        tools = await s.list_tools()
        nodes = await s.call_tool("ros_node_list", {})
        move = await s.call_tool("turtle_move", {"distance": 0.5})
        return {
            "tools": [t.name for t in tools.tools],
            "read_only": {t.name: bool(t.annotations and t.annotations.read_only_hint) for t in tools.tools},
            "destructive": {t.name: bool(t.annotations and t.annotations.destructive_hint) for t in tools.tools},
            "move_schema": next(t.input_schema for t in tools.tools if t.name == "turtle_move"),
            "nodes": text_of(nodes),
            "nodes_error": bool(nodes.is_error),
            "move": text_of(move),
            "move_error": bool(move.is_error),
        }


async def main():
    mode, target = sys.argv[1], sys.argv[2]
    out = {}
    for name, elicit in [("none", None), ("approve", approve), ("decline", decline)]:
        ASKED.clear()
        if mode == "stdio":
            params = StdioServerParameters(command=target, args=sys.argv[3:])
            async with stdio_client(params) as streams:
                out[name] = await session(streams, elicit)
        else:
            # The server's secret, as the operator's own client holds it.
            headers = {"Authorization": "Bearer " + os.environ["FERROSA_MCP_TOKEN"]}
            async with create_mcp_http_client(headers=headers) as http:
                async with streamable_http_client(target, http_client=http) as streams:
                    out[name] = await session(streams, elicit)
        out[name]["asked"] = list(ASKED)
    print(json.dumps(out))


asyncio.run(main())
