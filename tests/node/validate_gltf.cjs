// Runs the Khronos glTF validator on GLB files and prints one JSON report per file.
// Usage: node validate_gltf.cjs VALIDATOR_PACKAGE_DIR FILE...
"use strict";
const fs = require("fs");
const path = require("path");

const validator = require(path.resolve(process.argv[2]));
const files = process.argv.slice(3);

async function main() {
  const reports = [];
  for (const file of files) {
    const report = await validator.validateBytes(new Uint8Array(fs.readFileSync(file)), {
      uri: path.basename(file),
      maxIssues: 0, // no limit: every message is listed
    });
    reports.push({
      file,
      validatorVersion: report.validatorVersion,
      numErrors: report.issues.numErrors,
      numWarnings: report.issues.numWarnings,
      numInfos: report.issues.numInfos,
      numHints: report.issues.numHints,
      messages: report.issues.messages,
      generator: report.info && report.info.generator,
    });
  }
  process.stdout.write(JSON.stringify(reports, null, 1) + "\n");
}

main().catch((error) => {
  process.stderr.write(String(error) + "\n");
  process.exit(1);
});
