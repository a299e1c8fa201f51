// The status page: page.html and app.js, embedded into idm-web at build time (CMakeLists.txt).
#pragma once

namespace idm::web {

const char* page_html();
const char* page_js();

}  // namespace idm::web
