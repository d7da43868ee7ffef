// Validates a .glb with the Khronos glTF validator and prints its summary line and any errors or
// warnings; exits 1 when the file has errors. Usage: node validate_gltf.mjs FILE.glb
import fs from 'node:fs';
import validator from 'gltf-validator';

const file = process.argv[2];
const report = await validator.validateBytes(new Uint8Array(fs.readFileSync(file)), {
  maxIssues: 1000,
});
const i = report.issues;
console.log(`gltf-validator ${report.validatorVersion}: ${file}: errors=${i.numErrors} warnings=${i.numWarnings} infos=${i.numInfos} hints=${i.numHints}`);
const infoCodes = new Map();
for (const m of i.messages) {
  if (m.severity <= 1) console.log(`  ${m.severity === 0 ? 'error' : 'warning'} ${m.code} at ${m.pointer}: ${m.message}`);
  else infoCodes.set(m.code, (infoCodes.get(m.code) || 0) + 1);
}
for (const [code, n] of infoCodes) console.log(`  info/hint ${code} ×${n}`);
console.log(`  ${report.info.drawCallCount} draw calls, ${report.info.totalTriangleCount} triangles, ${report.info.materialCount} materials, extensions ${report.info.extensionsUsed.join(', ')}`);
process.exit(i.numErrors === 0 ? 0 : 1);
