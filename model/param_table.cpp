#include "model/param_table.h"

namespace idm::model {

std::string markdown_header() {
  return "| key | unit | default | range | meaning |\n|---|---|---|---|---|\n";
}

}  // namespace idm::model
