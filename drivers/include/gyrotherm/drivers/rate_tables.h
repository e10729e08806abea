// Building the station's rate table from its [table] connection.
#pragma once

#include <memory>
#include <string>

#include "gyrotherm/core/result.h"
#include "gyrotherm/drivers/rate_table.h"

namespace gyrotherm::drivers {

// By `connection.profile`: "acutrol" → AcutrolTable, "aero" → AeroTable
// (which takes `declared` as its limits: it cannot be asked). Does not
// connect. Unknown profile: permanent error naming it.
Result<std::unique_ptr<RateTable>> make_rate_table(const TableConnection& connection,
                                                   const TableLimits& declared,
                                                   std::string name = "table");

}  // namespace gyrotherm::drivers
