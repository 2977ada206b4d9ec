-- Each servo's wear verdict across a fleet, exactly as `lj9da-bridge record trend` judges it
-- (src/record/trend.rs, `judge`; docs/wear.md), over the view `flights`: the files
-- `flights/*.parquet` of one or more `lj9da-bridge record parquet` exports.
--
-- A servo is an aircraft's servo: aircraft, name, bus and ID. Its flights are ordered by the
-- run's start (`run_start_unix_ns`). Its baseline is the median of each figure over its first
-- 5 flights (a figure's missing values left out; the middle value, or the mean of the two
-- middle ones). From the sixth flight on, each flight is marked by each of:
--   friction            more than +25 % over its baseline;
--   holding current     more than +25 % over its baseline, and at least +0.02 A;
--   heating             more than +25 % over its baseline, the flight's temperature rise
--                       also at least 2 °C above the baseline's;
--   temperature margin  more than 10 °C smaller than its baseline.
-- The verdict: `inspect` when the latest flight is marked (`triggers`: what marked it;
-- `marked_since`: the first of the marked flights that reach the latest, 1-based), `watch`
-- when an earlier flight was marked but not the latest (`triggers`, `marked_since`: the last
-- marked flight's), `ok` otherwise, and `baseline` while it has no flight beyond its first 5.
-- (`record trend --since` has no counterpart here: filter `flights` on `flight_start` first.)
--
-- One statement of plain SQL (CTEs, window functions, CASE, concat_ws), run unchanged by
-- DuckDB and by Spark SQL: benches/fleet/duckdb_verdicts.py, benches/fleet/spark_verdicts.py.
-- Divisions are guarded (Spark's ANSI mode raises on a division by zero), constants are
-- DOUBLE (a plain 0.25 is a DECIMAL in both), and no integer is divided.

WITH constants AS (
  SELECT
    5 AS baseline_flights,
    CAST(0.25 AS DOUBLE) AS rise_limit,
    CAST(0.02 AS DOUBLE) AS holding_min_rise_a,
    CAST(2.0 AS DOUBLE) AS heating_min_extra_c,
    CAST(10.0 AS DOUBLE) AS margin_min_drop_c
),

-- Each servo's flights, numbered from 0 in date order.
numbered AS (
  SELECT
    f.*,
    ROW_NUMBER() OVER (
      PARTITION BY f.aircraft, f.servo, f.bus, f.id ORDER BY f.run_start_unix_ns
    ) - 1 AS i,
    COUNT(*) OVER (PARTITION BY f.aircraft, f.servo, f.bus, f.id) AS n_flights
  FROM flights f
),

-- The values of the baseline's flights, one row per figure.
base_values AS (
  SELECT n.aircraft, n.servo, n.bus, n.id, 'friction' AS figure, n.friction_ma_per_mm_s AS v
  FROM numbered n CROSS JOIN constants k
  WHERE n.i < k.baseline_flights AND n.friction_ma_per_mm_s IS NOT NULL
  UNION ALL
  SELECT n.aircraft, n.servo, n.bus, n.id, 'holding', n.holding_a
  FROM numbered n CROSS JOIN constants k
  WHERE n.i < k.baseline_flights AND n.holding_a IS NOT NULL
  UNION ALL
  SELECT n.aircraft, n.servo, n.bus, n.id, 'heating', n.heating_c_per_min
  FROM numbered n CROSS JOIN constants k
  WHERE n.i < k.baseline_flights AND n.heating_c_per_min IS NOT NULL
  UNION ALL
  SELECT n.aircraft, n.servo, n.bus, n.id, 'rise', n.rise_c
  FROM numbered n CROSS JOIN constants k
  WHERE n.i < k.baseline_flights AND n.rise_c IS NOT NULL
  UNION ALL
  SELECT n.aircraft, n.servo, n.bus, n.id, 'margin', n.margin_c
  FROM numbered n CROSS JOIN constants k
  WHERE n.i < k.baseline_flights AND n.margin_c IS NOT NULL
),

ranked AS (
  SELECT
    b.*,
    ROW_NUMBER() OVER (PARTITION BY b.aircraft, b.servo, b.bus, b.id, b.figure ORDER BY b.v) AS r,
    COUNT(*) OVER (PARTITION BY b.aircraft, b.servo, b.bus, b.id, b.figure) AS c
  FROM base_values b
),

-- The median: the middle value (c odd), or the mean of the two middle ones (c even). Rank r
-- is a middle one when c <= 2r <= c + 2.
medians AS (
  SELECT aircraft, servo, bus, id, figure, AVG(v) AS median
  FROM ranked
  WHERE 2 * r >= c AND 2 * r <= c + 2
  GROUP BY aircraft, servo, bus, id, figure
),

servos AS (
  SELECT aircraft, servo, bus, id, MAX(n_flights) AS n_flights
  FROM numbered
  GROUP BY aircraft, servo, bus, id
),

baseline AS (
  SELECT
    s.aircraft, s.servo, s.bus, s.id, s.n_flights,
    MAX(CASE WHEN m.figure = 'friction' THEN m.median END) AS b_friction,
    MAX(CASE WHEN m.figure = 'holding' THEN m.median END) AS b_holding,
    MAX(CASE WHEN m.figure = 'heating' THEN m.median END) AS b_heating,
    MAX(CASE WHEN m.figure = 'rise' THEN m.median END) AS b_rise,
    MAX(CASE WHEN m.figure = 'margin' THEN m.median END) AS b_margin
  FROM servos s
  LEFT JOIN medians m
    ON m.aircraft = s.aircraft AND m.servo = s.servo AND m.bus = s.bus AND m.id = s.id
  GROUP BY s.aircraft, s.servo, s.bus, s.id, s.n_flights
),

-- A figure's change over its baseline, (value - baseline) / baseline: null where either is
-- missing or the baseline is not above 0.
changes AS (
  SELECT
    n.aircraft, n.servo, n.bus, n.id, n.i, n.run_start_unix_ns, n.flight_start,
    n.friction_ma_per_mm_s, n.holding_a, n.heating_c_per_min, n.rise_c, n.margin_c,
    b.b_friction, b.b_holding, b.b_heating, b.b_rise, b.b_margin,
    CASE WHEN b.b_friction > 0
      THEN (n.friction_ma_per_mm_s - b.b_friction) / b.b_friction END AS friction_change,
    CASE WHEN b.b_holding > 0
      THEN (n.holding_a - b.b_holding) / b.b_holding END AS holding_change,
    CASE WHEN b.b_heating > 0
      THEN (n.heating_c_per_min - b.b_heating) / b.b_heating END AS heating_change
  FROM numbered n
  JOIN baseline b
    ON b.aircraft = n.aircraft AND b.servo = n.servo AND b.bus = n.bus AND b.id = n.id
),

-- Each flight's marks (none on the baseline's flights).
judged AS (
  SELECT
    c.*,
    CASE WHEN c.i >= k.baseline_flights
      AND c.friction_change > k.rise_limit
      AND c.friction_ma_per_mm_s - c.b_friction >= 0
      THEN TRUE ELSE FALSE END AS friction,
    CASE WHEN c.i >= k.baseline_flights
      AND c.holding_change > k.rise_limit
      AND c.holding_a - c.b_holding >= k.holding_min_rise_a
      THEN TRUE ELSE FALSE END AS holding_current,
    CASE WHEN c.i >= k.baseline_flights
      AND c.heating_change > k.rise_limit
      AND c.heating_c_per_min - c.b_heating >= 0
      AND c.rise_c - c.b_rise >= k.heating_min_extra_c
      THEN TRUE ELSE FALSE END AS heating,
    CASE WHEN c.i >= k.baseline_flights
      AND c.b_margin - c.margin_c > k.margin_min_drop_c
      THEN TRUE ELSE FALSE END AS temperature_margin
  FROM changes c CROSS JOIN constants k
),

marked AS (
  SELECT
    j.*,
    CASE WHEN j.friction OR j.holding_current OR j.heating OR j.temperature_margin
      THEN TRUE ELSE FALSE END AS is_marked
  FROM judged j
),

-- Per servo: the latest flight, the last marked and the last unmarked one.
per_servo AS (
  SELECT
    m.aircraft, m.servo, m.bus, m.id,
    MAX(m.i) AS latest_i,
    MAX(CASE WHEN m.is_marked THEN m.i END) AS last_marked_i,
    MAX(CASE WHEN NOT m.is_marked THEN m.i END) AS last_unmarked_i
  FROM marked m
  GROUP BY m.aircraft, m.servo, m.bus, m.id
),

verdicts AS (
  SELECT
    b.aircraft, b.servo, b.bus, b.id, b.n_flights AS flights,
    CASE
      WHEN b.n_flights <= k.baseline_flights THEN 'baseline'
      WHEN s.last_marked_i = s.latest_i THEN 'inspect'
      WHEN s.last_marked_i IS NOT NULL THEN 'watch'
      ELSE 'ok'
    END AS verdict,
    -- The flight whose marks are the triggers, and the first marked flight (1-based).
    CASE
      WHEN b.n_flights <= k.baseline_flights THEN NULL
      WHEN s.last_marked_i = s.latest_i THEN s.latest_i
      ELSE s.last_marked_i
    END AS trigger_i,
    CASE
      WHEN b.n_flights <= k.baseline_flights THEN NULL
      WHEN s.last_marked_i = s.latest_i THEN s.last_unmarked_i + 2
      ELSE s.last_marked_i + 1
    END AS marked_since,
    b.b_friction, b.b_holding, b.b_heating, b.b_rise, b.b_margin
  FROM baseline b
  JOIN per_servo s
    ON s.aircraft = b.aircraft AND s.servo = b.servo AND s.bus = b.bus AND s.id = b.id
  CROSS JOIN constants k
)

SELECT
  v.aircraft,
  v.servo,
  v.bus,
  v.id,
  v.flights,
  v.verdict,
  concat_ws(', ',
    CASE WHEN m.friction THEN 'friction' END,
    CASE WHEN m.holding_current THEN 'holding current' END,
    CASE WHEN m.heating THEN 'heating' END,
    CASE WHEN m.temperature_margin THEN 'temperature margin' END
  ) AS triggers,
  v.marked_since,
  -- The deciding flight (the latest when inspect, the last marked when watch): its UTC date,
  -- and its run's start as in `flights` (a plain integer, which every client reads).
  CAST(m.flight_start AS DATE) AS trigger_flight_date,
  m.run_start_unix_ns AS trigger_run_start_unix_ns,
  CASE WHEN m.friction IS NULL THEN FALSE ELSE m.friction END AS friction,
  CASE WHEN m.holding_current IS NULL THEN FALSE ELSE m.holding_current END AS holding_current,
  CASE WHEN m.heating IS NULL THEN FALSE ELSE m.heating END AS heating,
  CASE WHEN m.temperature_margin IS NULL THEN FALSE ELSE m.temperature_margin END
    AS temperature_margin,
  m.friction_change,
  m.holding_change,
  m.heating_change,
  v.b_friction AS baseline_friction_ma_per_mm_s,
  v.b_holding AS baseline_holding_a,
  v.b_heating AS baseline_heating_c_per_min,
  v.b_rise AS baseline_rise_c,
  v.b_margin AS baseline_margin_c
FROM verdicts v
LEFT JOIN marked m
  ON m.aircraft = v.aircraft AND m.servo = v.servo AND m.bus = v.bus AND m.id = v.id
  AND m.i = v.trigger_i
ORDER BY
  CASE v.verdict WHEN 'inspect' THEN 0 WHEN 'watch' THEN 1 WHEN 'ok' THEN 2 ELSE 3 END,
  v.aircraft, v.servo, v.bus, v.id;
