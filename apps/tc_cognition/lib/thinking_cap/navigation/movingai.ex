defmodule ThinkingCap.Navigation.MovingAI do
  @moduledoc """
  Reads the Moving AI Lab's grid path-finding benchmarks
  (movingai.com/benchmarks/formats.html): `.map` files into a
  `ThinkingCap.Navigation.Grid`, `.scen` files into lists of problems.

  A map starts with the header lines `type octile`, `height H`, `width W`
  and `map`, then H rows of W cells: `.`, `G` and `S` are passable, `@`,
  `O`, `T` and `W` blocked.

  ## Coordinates

  Moving AI's `(x, y)` is (column, row counted from the **top**); the
  Grid's cell `{col, row}` counts rows from the **bottom**. So point
  `(x, y)` is cell `{x, height - 1 - y}` (`to_cell/2`, back with
  `to_xy/2`), map text row `y` is grid row `height - 1 - y`, and the
  problems of a `.scen` file come with both: `start`/`goal` as grid cells,
  `start_xy`/`goal_xy` as written in the file. The grid has resolution 1
  and origin `{0.0, 0.0}`.

  Errors are `{:error, "FILE:LINE: what is wrong"}` (line 1-based).
  """

  alias ThinkingCap.Navigation.{AStar, Grid}

  @type problem :: %{
          bucket: non_neg_integer(),
          map: String.t(),
          width: pos_integer(),
          height: pos_integer(),
          start: Grid.cell(),
          goal: Grid.cell(),
          start_xy: {non_neg_integer(), non_neg_integer()},
          goal_xy: {non_neg_integer(), non_neg_integer()},
          optimal_length: float()
        }

  @doc "Reads a `.map` file into a grid (see `parse_map/2`)."
  @spec load_map(Path.t()) :: {:ok, Grid.t()} | {:error, String.t()}
  def load_map(path) do
    case File.read(path) do
      {:ok, text} -> parse_map(text, path)
      {:error, reason} -> {:error, "#{path}: #{:file.format_error(reason)}"}
    end
  end

  @doc """
  Parses the text of a `.map` file; `name` (the file's name) prefixes the
  error messages.
  """
  @spec parse_map(String.t(), String.t()) :: {:ok, Grid.t()} | {:error, String.t()}
  def parse_map(text, name \\ "map") do
    lines = text |> lines() |> Enum.with_index(1)

    with {:ok, header, rows} <- header(lines, name, %{}),
         {:ok, height} <- dimension(header, "height", name),
         {:ok, width} <- dimension(header, "width", name),
         {:ok, rows} <- rows(rows, width, height, name, []) do
      # `rows/5` reverses the text's rows: the grid's bytes are bottom row first
      {:ok, Grid.new(width, height, cells: IO.iodata_to_binary(rows))}
    end
  end

  @doc "Reads a `.scen` file into its problems (see `parse_scenarios/2`)."
  @spec load_scenarios(Path.t()) :: {:ok, [problem()]} | {:error, String.t()}
  def load_scenarios(path) do
    case File.read(path) do
      {:ok, text} -> parse_scenarios(text, path)
      {:error, reason} -> {:error, "#{path}: #{:file.format_error(reason)}"}
    end
  end

  @doc """
  Parses the text of a `.scen` file: a `version 1` line, then one problem a
  line, tab-separated `bucket map width height start_x start_y goal_x
  goal_y optimal_length`. Problems come in file order; `name` prefixes the
  error messages.
  """
  @spec parse_scenarios(String.t(), String.t()) :: {:ok, [problem()]} | {:error, String.t()}
  def parse_scenarios(text, name \\ "scen") do
    case text |> lines() |> Enum.with_index(1) |> Enum.reject(&blank?/1) do
      [{"version " <> _, _} | problems] ->
        problems
        |> Enum.reduce_while([], fn {line, n}, acc ->
          case problem(line) do
            {:ok, p} -> {:cont, [p | acc]}
            {:error, why} -> {:halt, {:error, "#{name}:#{n}: #{why}"}}
          end
        end)
        |> case do
          {:error, _} = error -> error
          problems -> {:ok, Enum.reverse(problems)}
        end

      [{line, n} | _] ->
        {:error, "#{name}:#{n}: expected \"version 1\", got #{inspect(line)}"}

      [] ->
        {:error, "#{name}:1: empty scenario file"}
    end
  end

  @typedoc """
  A problem solved by `solve/3`: the problem, the `cost` found (`nil`
  when A* found no path), whether it is `optimal` (within 1e-4 of the
  file's optimal length), the cells `expanded` and the wall time `us` of
  the `ThinkingCap.Navigation.AStar.plan/4` call in microseconds.
  """
  @type solution :: %{
          problem: problem(),
          cost: float() | nil,
          optimal: boolean(),
          expanded: non_neg_integer(),
          us: non_neg_integer()
        }

  @doc """
  Solves every problem with A* on `grid` (the problems' map), timing each
  plan. Options: `jobs` (default 1), how many problems run at once; each
  problem is still timed on its own, so with more jobs than idle cores the
  times grow. One untimed plan runs first (loading the code). Solutions
  come in the problems' order.
  """
  @spec solve(Grid.t(), [problem()], keyword()) :: [solution()]
  def solve(%Grid{} = grid, problems, opts \\ []) do
    one = fn p ->
      {us, result} = :timer.tc(fn -> AStar.plan(grid, p.start, p.goal) end)

      case result do
        {:ok, %{cost: cost, expanded: n}} ->
          optimal = abs(cost - p.optimal_length) <= 1.0e-4
          %{problem: p, cost: cost, optimal: optimal, expanded: n, us: us}

        {:error, _} ->
          %{problem: p, cost: nil, optimal: false, expanded: 0, us: us}
      end
    end

    # one untimed plan first, so that loading the code is not timed
    with [p | _] <- problems, do: AStar.plan(grid, p.start, p.goal)

    case Keyword.get(opts, :jobs, 1) do
      1 ->
        Enum.map(problems, one)

      jobs ->
        problems
        |> Task.async_stream(one, max_concurrency: jobs, timeout: :infinity)
        |> Enum.map(fn {:ok, solution} -> solution end)
    end
  end

  @doc "The grid cell of Moving AI point `(x, y)` on a map `height` rows high."
  @spec to_cell(pos_integer(), {integer(), integer()}) :: Grid.cell()
  def to_cell(height, {x, y}), do: {x, height - 1 - y}

  @doc "The Moving AI point `(x, y)` of a grid cell on a map `height` rows high."
  @spec to_xy(pos_integer(), Grid.cell()) :: {integer(), integer()}
  def to_xy(height, {col, row}), do: {col, height - 1 - row}

  ## Maps

  defp lines(text), do: String.split(text, ["\r\n", "\n"])

  defp blank?({line, _}), do: String.trim(line) == ""

  defp header([{line, n} | rest], name, acc) do
    case String.split(String.trim(line)) do
      ["map"] -> {:ok, acc, rest}
      [] -> header(rest, name, acc)
      [key, value] -> header(rest, name, Map.put(acc, key, {value, n}))
      _ -> {:error, "#{name}:#{n}: bad header line #{inspect(line)}"}
    end
  end

  defp header([], name, _acc), do: {:error, "#{name}: no \"map\" line ending the header"}

  defp dimension(header, key, name) do
    case header do
      %{^key => {value, n}} ->
        case Integer.parse(value) do
          {v, ""} when v > 0 -> {:ok, v}
          _ -> {:error, "#{name}:#{n}: bad #{key} #{inspect(value)}"}
        end

      _ ->
        {:error, "#{name}: no #{key} in the header"}
    end
  end

  defp rows(_lines, _width, 0, _name, acc), do: {:ok, acc}

  defp rows([{line, n} | rest], width, left, name, acc) do
    cond do
      line == "" and Enum.all?(rest, &blank?/1) ->
        {:error, "#{name}:#{n}: #{left} map row(s) missing"}

      byte_size(line) != width ->
        {:error, "#{name}:#{n}: row of #{byte_size(line)} cells, expected #{width}"}

      bad = bad_cell(line) ->
        {:error, "#{name}:#{n}: unknown terrain #{inspect(<<bad>>)}"}

      true ->
        rows(rest, width, left - 1, name, [row_bytes(line) | acc])
    end
  end

  defp rows([], _width, left, name, _acc),
    do: {:error, "#{name}: #{left} map row(s) missing"}

  defp bad_cell(line) do
    Enum.find(:binary.bin_to_list(line), fn c -> c not in ~c".GS@OTW" end)
  end

  defp row_bytes(line), do: for(<<c <- line>>, into: <<>>, do: <<blocked(c)>>)

  defp blocked(c) when c in ~c".GS", do: 0
  defp blocked(_), do: 1

  ## Scenarios

  defp problem(line) do
    fields =
      case String.split(line, "\t") do
        fields when length(fields) == 9 -> fields
        _ -> String.split(line)
      end

    with [bucket, map, width, height, sx, sy, gx, gy, optimal] <- fields,
         {:ok, [bucket, width, height, sx, sy, gx, gy]} <-
           integers([bucket, width, height, sx, sy, gx, gy]),
         {:ok, optimal} <- length_of(optimal),
         true <- width > 0 and height > 0,
         :ok <- inside({sx, sy}, width, height, "start"),
         :ok <- inside({gx, gy}, width, height, "goal") do
      {:ok,
       %{
         bucket: bucket,
         map: map,
         width: width,
         height: height,
         start: to_cell(height, {sx, sy}),
         goal: to_cell(height, {gx, gy}),
         start_xy: {sx, sy},
         goal_xy: {gx, gy},
         optimal_length: optimal
       }}
    else
      fields when is_list(fields) -> {:error, "#{length(fields)} fields, expected 9"}
      false -> {:error, "bad map dimensions"}
      {:error, _} = error -> error
    end
  end

  defp integers(values) do
    Enum.reduce_while(values, {:ok, []}, fn value, {:ok, acc} ->
      case Integer.parse(value) do
        {v, ""} when v >= 0 -> {:cont, {:ok, acc ++ [v]}}
        _ -> {:halt, {:error, "bad integer #{inspect(value)}"}}
      end
    end)
  end

  defp length_of(value) do
    case Float.parse(value) do
      {v, ""} when v >= 0 -> {:ok, v}
      _ -> {:error, "bad optimal length #{inspect(value)}"}
    end
  end

  defp inside({x, y}, width, height, what) do
    if x < width and y < height,
      do: :ok,
      else: {:error, "#{what} (#{x}, #{y}) outside the #{width}×#{height} map"}
  end
end
