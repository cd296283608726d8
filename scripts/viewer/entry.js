// The report viewer's library: what src/metrics/viewer.rs's page script uses, bundled by
// scripts/setup/50_viewer.sh into one classic script (global `FantasyViewerLib`) so that
// report.html can inline it and open from disk with no module loading and no network.
export * as THREE from "three";
export { OrbitControls } from "three/addons/controls/OrbitControls.js";
export { SparkRenderer, SplatMesh, SplatFileType } from "@sparkjsdev/spark";
