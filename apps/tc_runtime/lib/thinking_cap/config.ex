defmodule ThinkingCap.Config do
  @moduledoc """
  Reads and validates the three description files of a run:

    * `*.adf` - architecture: modules, where and how they run
      (`ThinkingCap.Config.ADF`);
    * `*.rdf` - robot: footprint, kinematics, sensors, error models
      (`ThinkingCap.Config.RDF`);
    * `*.wdf` - world: walls, rooms, doors, beacons, waypoints, an optional
      ROS occupancy map (`ThinkingCap.Config.WDF`).

  A description file holds one keyword list written in Elixir's term syntax
  (the syntax of `mix.exs` keyword lists). It is read with
  `Code.string_to_quoted/2` and **never evaluated**: anything but literal
  data (numbers, atoms, strings, lists, tuples, maps, module names) is
  refused. Every problem is reported as `file:line:column: message`, all of
  a file's problems at once (at most 50, then how many more); unknown keys
  are errors, with a "did you mean" when a known key is close.

  Any byte sequence gets an answer in time and memory bounded by its size:
  a file is refused unread above 4 MB, and before it is parsed when it is
  not UTF-8 or its brackets nest deeper than 64; parsing makes at most
  2,000 new atoms per file (the names of waypoints, sensors and the like),
  and refuses the file past that. Each kind's module documents its keys and
  defaults, in one table per section.

      {:ok, %ThinkingCap.Config.ADF{}} = ThinkingCap.Config.read("priv/examples/office.adf")
      {:error, [%ThinkingCap.Config.Error{} | _]} = ThinkingCap.Config.read("broken.rdf")
  """

  alias ThinkingCap.Config.{ADF, Error, Literal, RDF, RosMap, Source, WDF}

  @kinds %{".adf" => ADF, ".rdf" => RDF, ".wdf" => WDF}

  @type description :: ADF.t() | RDF.t() | WDF.t()

  @doc "Reads and validates a description file; the kind comes from its extension."
  @spec read(Path.t()) :: {:ok, description()} | {:error, [Error.t()]}
  def read(path) do
    with {:ok, kind} <- kind(path),
         {:ok, source} <- Source.read(path),
         {:ok, data, positions} <- Literal.parse(source, path),
         {:ok, description} <- kind.from_data(data, path, positions) do
      {:ok, description}
    else
      {:error, errors} -> {:error, Error.cap(errors)}
    end
  end

  @doc """
  An ADF given as a path (read and checked) or already read:
  `{:ok, adf}`, or `{:error, message}` with every error, or saying that
  the file is no ADF.
  """
  @spec adf(ADF.t() | Path.t()) :: {:ok, ADF.t()} | {:error, String.t()}
  def adf(%ADF{} = adf), do: {:ok, adf}

  def adf(path) when is_binary(path) do
    case read(path) do
      {:ok, %ADF{} = adf} -> {:ok, adf}
      {:ok, _other} -> {:error, "#{path} is not an ADF"}
      {:error, errors} -> {:error, format_errors(errors)}
    end
  end

  @doc "Like `read/1`, but raises `ArgumentError` with every error."
  @spec read!(Path.t()) :: description()
  def read!(path) do
    case read(path) do
      {:ok, description} ->
        description

      {:error, errors} ->
        raise ArgumentError, "invalid description file:\n" <> format_errors(errors)
    end
  end

  @typedoc """
  A reader of another kind of file, by extension (`".urdf"`): it returns
  `{:ok, _}` or `{:error, errors}` (at most 50 and a count of the rest).
  """
  @type reader :: (Path.t() -> {:ok, term()} | {:error, [Error.t()]})

  @doc """
  Validates any number of files; returns every error of every file.
  Description files are read with `read/1`, ROS map files (`*.yaml`)
  with `ThinkingCap.Config.RosMap.load/1` (the YAML and the image it
  names), and other extensions with the `readers` given (the URDF reader
  of `tc_robot`, a layer above this one, comes so from `mix tc.check`).
  """
  @spec check([Path.t()], %{optional(String.t()) => reader()}) :: [Error.t()]
  def check(paths, readers \\ %{}) do
    readers = Map.merge(%{".yaml" => &RosMap.load/1}, readers)

    Enum.flat_map(paths, fn path ->
      read = Map.get(readers, Path.extname(path), &read/1)

      case read.(path) do
        {:ok, _} -> []
        {:error, errors} -> errors
      end
    end)
  end

  @doc "One `file:line:column: message` line per error."
  @spec format_errors([Error.t()]) :: String.t()
  def format_errors(errors), do: Enum.map_join(errors, "\n", &to_string/1)

  defp kind(path) do
    case Map.fetch(@kinds, Path.extname(path)) do
      {:ok, kind} ->
        {:ok, kind}

      :error ->
        {:error,
         [
           Error.new(
             path,
             {0, 0},
             "unknown kind of file: expected a .adf, .rdf or .wdf description file (mix tc.check also reads .yaml maps and .urdf files)"
           )
         ]}
    end
  end
end
