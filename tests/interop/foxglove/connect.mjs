// Connects Foxglove's own WebSocket client (@foxglove/ws-protocol) to `url` as the app does, with
// the protocol's v1 under the names Foxglove's SDK servers accept (`foxglove.sdk.v1`: schemas
// inline in the advertisement, as ws-protocol's client reads them) and its original name. The
// server may not be up yet: a client per attempt (for 30 s), `setup` putting every handler in
// place before its socket opens (the server's first messages come with the handshake).

import wsProtocol from "@foxglove/ws-protocol";
import WebSocket from "ws";

const { FoxgloveClient } = wsProtocol;
const SUBPROTOCOLS = ["foxglove.sdk.v1", FoxgloveClient.SUPPORTED_SUBPROTOCOL];

export async function connect(url, setup) {
  for (let attempt = 0; attempt < 300; attempt++) {
    const client = new FoxgloveClient({ ws: new WebSocket(url, SUBPROTOCOLS) });
    setup(client);
    const opened = await new Promise((resolve) => {
      client.on("open", () => resolve(true));
      client.on("error", () => resolve(false));
    });
    if (opened) return client;
    client.close();
    await new Promise((r) => setTimeout(r, 100));
  }
  throw new Error(`cannot connect to ${url}`);
}
