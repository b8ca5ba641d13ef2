// Acts on ttball's live view with Foxglove's own WebSocket client (@foxglove/ws-protocol, the
// protocol the Foxglove app speaks), as a user of the app would: reads every parameter, sets
// some (a good value, one out of range, a read-only one, a wrong type), subscribes to updates,
// and calls each advertised service with a request from REQUESTS.json, encoded and decoded with
// the service's own ros2msg schemas (@foxglove/rosmsg, @foxglove/rosmsg2-serialization).
//
// Usage: node act_client.mjs ws://HOST:PORT REQUESTS.json REPORT.json
//
// REQUESTS.json: {"sets": [[{name, value}, ...], ...], "calls": {service name: request}}.
// REPORT.json: the server's capabilities, the services advertised (name, type, schema names),
// the values of every parameter, after each set the values it answered, the status messages,
// the parameter updates seen, and per service the decoded response or the failure.

import { readFile, writeFile } from "node:fs/promises";
import { plain } from "./plain.mjs";
import { connect } from "./connect.mjs";
import { parse } from "@foxglove/rosmsg";
import { MessageReader, MessageWriter } from "@foxglove/rosmsg2-serialization";

const [url, requestsPath, reportPath] = process.argv.slice(2);
const requests = JSON.parse(await readFile(requestsPath, "utf8"));
const report = {
  capabilities: [],
  services: [],
  all: null,
  sets: [],
  statuses: [],
  updates: [],
  calls: {},
  problems: [],
};

const waiting = new Map(); // request id or call id -> resolve
const answered = (key, value) => {
  const resolve = waiting.get(key);
  if (resolve) {
    waiting.delete(key);
    resolve(value);
  }
};
const ask = (key, send) =>
  new Promise((resolve, reject) => {
    waiting.set(key, resolve);
    send();
    setTimeout(() => reject(new Error(`no answer to ${key} in 10 s`)), 10000);
  });

let servicesAdvertised;
const advertised = new Promise((resolve) => (servicesAdvertised = resolve));
const services = [];
const client = await connect(url, (client) => {
  client.on("serverInfo", (info) => (report.capabilities = info.capabilities));
  client.on("status", (status) => report.statuses.push(status.message));
  client.on("advertiseServices", (list) => {
    for (const s of list) {
      services.push(s);
      report.services.push({
        name: s.name,
        type: s.type,
        request: s.request?.schemaName,
        response: s.response?.schemaName,
        encoding: s.request?.encoding,
      });
    }
    servicesAdvertised();
  });
  client.on("parameterValues", ({ parameters, id }) => {
    if (id === undefined) report.updates.push(...parameters);
    else answered(id, parameters);
  });
  client.on("serviceCallResponse", ({ callId, data }) => answered(`call${callId}`, { data }));
  client.on("serviceCallFailure", ({ callId, message }) => answered(`call${callId}`, { message }));
});

const byName = (parameters) => Object.fromEntries(parameters.map((p) => [p.name, p.value]));
try {
  report.all = byName(await ask("all", () => client.getParameters([], "all")));
  client.subscribeParameterUpdates(Object.keys(report.all));
  for (const [k, set] of requests.sets.entries()) {
    report.sets.push(byName(await ask(`set${k}`, () => client.setParameters(set, `set${k}`))));
  }
  await advertised;
  let callId = 0;
  for (const service of services) {
    const request = requests.calls[service.name];
    if (!request) continue;
    const writer = new MessageWriter(parse(service.request.schema, { ros2: true }));
    const reader = new MessageReader(parse(service.response.schema, { ros2: true }));
    callId += 1;
    const answer = await ask(`call${callId}`, () =>
      client.sendServiceCallRequest({
        serviceId: service.id,
        callId,
        encoding: "cdr",
        data: new DataView(writer.writeMessage(request).buffer),
      }),
    );
    report.calls[service.name] =
      answer.data !== undefined
        ? { response: plain(reader.readMessage(answer.data)) }
        : { failure: answer.message };
  }
  // Updates and statuses still on their way.
  await new Promise((r) => setTimeout(r, 300));
} catch (e) {
  report.problems.push(String(e));
}
client.close();
await writeFile(reportPath, JSON.stringify(report, null, 1));
process.exit(0);
