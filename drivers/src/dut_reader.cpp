#include "gyrotherm/drivers/dut_link.h"

namespace gyrotherm::drivers {

Result<std::unique_ptr<DutSource>> make_dut_source(const DutLink& link, const Clock&) {
  if (auto ch = dut_channels(link); !ch.ok()) return ch.error();
  return Error::Permanent("make_dut_source: not implemented yet (i18-proto)");
}

}  // namespace gyrotherm::drivers
