// Watches ttball's live view with Foxglove's own WebSocket client (@foxglove/ws-protocol, the
// protocol the Foxglove app speaks), as the app would: connect, subscribe to every advertised
// channel, decode each message from the channel's ros2msg schema (@foxglove/rosmsg,
// @foxglove/rosmsg2-serialization).
//
// Usage: node live_client.mjs ws://HOST:PORT SECONDS REPORT.json
//
// Connects (retrying for 30 s until the server is up), then listens for SECONDS after the first message
// or until the server closes. REPORT.json: the server's name, every channel advertised (topic,
// encoding, schema name and encoding), per topic the messages received and decoded (with the
// first decoded message and its log time), and every problem (a message that does not decode,
// or leaves bytes over, or an error the server reports).

import { writeFile } from "node:fs/promises";
import { plain } from "./plain.mjs";
import { connect } from "./connect.mjs";
import { parse } from "@foxglove/rosmsg";
import { MessageReader } from "@foxglove/rosmsg2-serialization";

const [url, seconds, reportPath] = process.argv.slice(2);
const report = { server: null, channels: [], topics: {}, problems: [] };
const channels = new Map();

let deadline = null;
let finish;
const done = new Promise((resolve) => {
  finish = resolve;
  setInterval(() => {
    if (deadline && Date.now() > deadline) resolve();
  }, 50);
});
let active = null;
const client = await connect(url, (client) => {
  // The server closing the connection ends the watch (a failed attempt's close does not).
  client.on("close", () => client === active && finish());
  client.on("serverInfo", (info) => {
    report.server = { name: info.name, capabilities: info.capabilities };
  });
  // The server's errors (e.g. a subscription it refused) are problems of the watch.
  client.on("status", ({ level, message }) => {
    if (level >= 2) report.problems.push(`server: ${message}`);
  });
  client.on("advertise", (advertised) => {
    for (const channel of advertised) {
      report.channels.push({
        topic: channel.topic,
        encoding: channel.encoding,
        schemaName: channel.schemaName,
        schemaEncoding: channel.schemaEncoding,
      });
      let reader = null;
      try {
        reader = new MessageReader(parse(channel.schema, { ros2: true }));
      } catch (e) {
        report.problems.push(`${channel.topic}: schema does not parse: ${e}`);
      }
      const subscription = client.subscribe(channel.id);
      channels.set(subscription, { topic: channel.topic, reader });
    }
  });
  client.on("message", ({ subscriptionId, timestamp, data }) => {
    const channel = channels.get(subscriptionId);
    if (!channel) return;
    deadline ??= Date.now() + Number(seconds) * 1000;
    const topic = (report.topics[channel.topic] ??= { received: 0, decoded: 0 });
    topic.received++;
    try {
      const message = channel.reader.readMessage(data);
      if (channel.reader.lastReadHadTrailingBytes()) {
        report.problems.push(`${channel.topic}: trailing bytes`);
      }
      topic.decoded++;
      if (!topic.first) {
        topic.first = plain(message);
        topic.first_log_time = timestamp.toString();
      }
    } catch (e) {
      report.problems.push(`${channel.topic}: ${e}`);
    }
  });
});
active = client;
await done;
await writeFile(reportPath, JSON.stringify(report, null, 1));
client.close();
process.exit(0);
