#pragma once
// The viewer's text assets, embedded at build time by cmake/embed_text.cmake (pipeline/
// CMakeLists.txt): three.js from the npm registry (viewer/package.json, pinned in
// viewer/package-lock.json) and the project's own viewer code in viewer/.
#include <string>

namespace flashtwin::pipeline::view3d_assets {

std::string three_js();   ///< three.js, CommonJS build (defines module.exports)
std::string viewer_js();  ///< viewer/view3d.js
std::string css();        ///< viewer/view3d.css
std::string body();       ///< viewer/view3d_body.html

}  // namespace flashtwin::pipeline::view3d_assets
