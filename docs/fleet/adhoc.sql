-- An ad-hoc question of a fleet's samples: each servo's minutes above 70 °C, per aircraft and
-- month (UTC: run it with the session's time zone set to UTC, as the scripts do), over the
-- view `samples`: the files `samples/*.parquet` of one or more `lj9da-bridge record parquet`
-- exports.
--
-- Counted as `record trend` counts its `hot_min` figure: the time from a telemetry sample
-- above 70 °C to the servo's next one in the flight (the sample's `next_telemetry_us`), a
-- break of more than 1 s not counted; so a month's minutes here are the sum of its flights'
-- `hot_min` in `flights`. A sum over the samples, then over each flight's few rows: no window
-- over the flight, no sort of the samples. The same statement runs in DuckDB and Spark SQL.

WITH per_flight AS (
  SELECT
    aircraft, flight_start, servo, bus, id,
    SUM(
      CASE
        WHEN temperature_c > 70 AND next_telemetry_us > 0 AND next_telemetry_us <= 1000000
        THEN next_telemetry_us
        ELSE 0
      END
    ) AS hot_us,
    MAX(temperature_c) AS peak_c
  FROM samples
  WHERE kind = 'telemetry'
  GROUP BY aircraft, flight_start, servo, bus, id
)
SELECT
  aircraft,
  CAST(date_trunc('month', flight_start) AS DATE) AS month,
  servo,
  bus,
  id,
  COUNT(*) AS flights,
  SUM(hot_us) / CAST(60000000 AS DOUBLE) AS minutes_above_70c,
  MAX(peak_c) AS peak_c
FROM per_flight
GROUP BY aircraft, CAST(date_trunc('month', flight_start) AS DATE), servo, bus, id
ORDER BY aircraft, month, servo, bus, id;
