#include "gyrotherm/drivers/rate_tables.h"

#include <fmt/format.h>

#include "gyrotherm/drivers/acutrol_table.h"
#include "gyrotherm/drivers/aero_table.h"

namespace gyrotherm::drivers {

Result<std::unique_ptr<RateTable>> make_rate_table(const TableConnection& connection,
                                                   const TableLimits& declared, std::string name) {
  if (connection.profile == "acutrol") {
    return std::unique_ptr<RateTable>(std::make_unique<AcutrolTable>(connection, std::move(name)));
  }
  if (connection.profile == "aero") {
    return std::unique_ptr<RateTable>(
        std::make_unique<AeroTable>(connection, declared, std::move(name)));
  }
  return Error::Permanent(
      fmt::format("{}: table profile \"{}\" is none of acutrol, aero", name, connection.profile));
}

}  // namespace gyrotherm::drivers
