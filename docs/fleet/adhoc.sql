-- An ad-hoc question of a fleet's samples: each servo's minutes above 70 °C, per aircraft and
-- month (UTC: run it with the session's time zone set to UTC, as the scripts do), over the
-- view `samples`: the files `samples/*.parquet` of one or more `lj9da-bridge record parquet`
-- exports.
--
-- Counted as `record trend` counts its `hot_min` figure: the time between two telemetry
-- samples of a servo in one flight whose earlier sample was above 70 °C, a break of more than
-- 1 s not counted, the samples taken in the order the flight's records hold them (`seq`); so
-- a month's minutes here are the sum of its flights' `hot_min` in `flights`. The same
-- statement runs in DuckDB and Spark SQL.

WITH telemetry AS (
  SELECT
    aircraft, flight_start, servo, bus, id, t_us, temperature_c,
    LAG(t_us) OVER (
      PARTITION BY aircraft, flight_start, servo, bus, id ORDER BY seq
    ) AS previous_t_us,
    LAG(temperature_c) OVER (
      PARTITION BY aircraft, flight_start, servo, bus, id ORDER BY seq
    ) AS previous_c
  FROM samples
  WHERE kind = 'telemetry'
)
SELECT
  aircraft,
  CAST(date_trunc('month', flight_start) AS DATE) AS month,
  servo,
  bus,
  id,
  COUNT(DISTINCT flight_start) AS flights,
  SUM(
    CASE
      WHEN previous_c > 70 AND t_us > previous_t_us AND t_us - previous_t_us <= 1000000
      THEN (t_us - previous_t_us) / CAST(60000000 AS DOUBLE)
      ELSE CAST(0 AS DOUBLE)
    END
  ) AS minutes_above_70c,
  MAX(temperature_c) AS peak_c
FROM telemetry
GROUP BY aircraft, CAST(date_trunc('month', flight_start) AS DATE), servo, bus, id
ORDER BY aircraft, month, servo, bus, id;
