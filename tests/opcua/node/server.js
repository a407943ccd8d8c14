// An OPC UA server not written by us (node-opcua), for the client's interoperability tests.
// Prints `ready PORT` once it serves and runs until its standard input closes.
//
//   node server.js [--limits N] [--hide-limits] [--many N] [--twice] [--pki DIR] [--secure]
//
// --limits N      every operation limit of ServerCapabilities/OperationLimits at N (nodes per
//                 read, write, browse and translate; monitored items per call), enforced
//                 with BadTooManyOperations.
// --hide-limits   the limits are enforced but not published (the variables read 0).
// --many N        variables Line1/Many/V0 .. V{N-1} (Int32, value k, writable).
// --twice         Line1/Many/V0 also reachable as Line1/Alias/V0 (one variable, two paths).
// --pki DIR       its own certificate (node-opcua's, subjectAltName with DNS first) there.
// --secure        Basic256Sha256 Sign and SignAndEncrypt endpoints besides None.
// --no-anonymous  anonymous users refused (a user name and password wanted).
// --count-refusals FILE  how many requests it refused as too many operations, in FILE.
"use strict";
const opcua = require("node-opcua");

function arg(name, fallback) {
  const i = process.argv.indexOf(name);
  if (i < 0) return fallback;
  return process.argv[i + 1];
}
const flag = (name) => process.argv.includes(name);

async function main() {
  const limits = Number(arg("--limits", "0"));
  const many = Number(arg("--many", "0"));
  const pki = arg("--pki", require("os").tmpdir() + "/iogate-node-opcua-" + process.pid);
  const operationLimits = limits > 0 ? {
    maxNodesPerRead: limits,
    maxNodesPerWrite: limits,
    maxNodesPerBrowse: limits,
    maxNodesPerTranslateBrowsePathsToNodeIds: limits,
    maxMonitoredItemsPerCall: limits,
    maxNodesPerMethodCall: limits,
    maxNodesPerRegisterNodes: limits,
    maxNodesPerHistoryReadData: limits,
  } : {};
  const certificateManager = new opcua.OPCUACertificateManager({
    rootFolder: pki,
    automaticallyAcceptUnknownCertificate: true,
  });
  const secure = flag("--secure");
  const server = new opcua.OPCUAServer({
    port: 0,
    resourcePath: "/UA/Peer",
    serverCertificateManager: certificateManager,
    securityPolicies: secure
      ? [opcua.SecurityPolicy.None, opcua.SecurityPolicy.Basic256Sha256]
      : [opcua.SecurityPolicy.None],
    securityModes: secure
      ? [opcua.MessageSecurityMode.None, opcua.MessageSecurityMode.Sign,
         opcua.MessageSecurityMode.SignAndEncrypt]
      : [opcua.MessageSecurityMode.None],
    allowAnonymous: !flag("--no-anonymous"),
    userManager: { isValidUser: (user, password) => user === "op" && password === "secret" },
    serverCapabilities: { operationLimits },
  });
  await server.initialize();
  const addressSpace = server.engine.addressSpace;
  const ns = addressSpace.getOwnNamespace();
  const line = ns.addObject({ organizedBy: addressSpace.rootFolder.objects, browseName: "Line1", nodeId: "s=Line1" });
  const folder = ns.addObject({ componentOf: line, browseName: "Many" });
  const first = [];
  for (let k = 0; k < many; k++) {
    let value = k;
    const v = ns.addVariable({
      componentOf: folder,
      browseName: "V" + k,
      nodeId: "s=Many.V" + k,
      dataType: "Int32",
      minimumSamplingInterval: 100,
      accessLevel: "CurrentRead | CurrentWrite",
      userAccessLevel: "CurrentRead | CurrentWrite",
      value: {
        get: () => new opcua.Variant({ dataType: opcua.DataType.Int32, value }),
        set: (variant) => { value = variant.value; return opcua.StatusCodes.Good; },
      },
    });
    if (k === 0) first.push(v);
  }
  if (flag("--twice") && first.length) {
    const alias = ns.addObject({ componentOf: line, browseName: "Alias" });
    alias.addReference({ referenceType: "Organizes", nodeId: first[0].nodeId });
  }
  if (flag("--hide-limits")) {
    const ol = addressSpace.findNode("ns=0;i=11704");
    for (const child of ol ? ol.getComponents().concat(ol.getPropertyByName ? [] : []) : []) {
      child.bindVariable({ get: () => new opcua.Variant({ dataType: opcua.DataType.UInt32, value: 0 }) }, true);
    }
    for (const ref of ol ? ol.findReferencesExAsObject("HasProperty") : []) {
      ref.bindVariable({ get: () => new opcua.Variant({ dataType: opcua.DataType.UInt32, value: 0 }) }, true);
    }
  }
  const countFile = arg("--count-refusals", null);
  if (countFile) {
    let refused = 0;
    require("fs").writeFileSync(countFile, "0");
    server.on("response", (response) => {
      const result = response.responseHeader && response.responseHeader.serviceResult;
      if (result && result.equals && result.equals(opcua.StatusCodes.BadTooManyOperations)) {
        refused += 1;
        require("fs").writeFileSync(countFile, String(refused));
      }
    });
  }
  await server.start();
  console.log("ready " + server.endpoints[0].port);
  process.stdin.on("end", async () => { await server.shutdown(0); process.exit(0); });
  process.stdin.resume();
}
main().catch((e) => { console.error(e); process.exit(1); });
