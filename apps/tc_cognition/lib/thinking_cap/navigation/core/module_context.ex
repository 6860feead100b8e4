defmodule ThinkingCap.Navigation.Core.ModuleContext do
  @moduledoc false
  # What the navigation modules read from their context at init: the
  # ADF's WDF and the robot's description. A file that cannot be read
  # raises ArgumentError naming the module and the problem, so the module
  # does not start rather than run blind.

  alias ThinkingCap.Config.WDF
  alias ThinkingCap.Robot.Description

  @doc "The ADF's WDF, or nil when the ADF gives none."
  @spec read_wdf(map()) :: WDF.t() | nil
  def read_wdf(%{wdf: path} = context) when is_binary(path) do
    case ThinkingCap.Config.read(path) do
      {:ok, %WDF{} = wdf} ->
        wdf

      {:ok, _} ->
        raise ArgumentError, "#{inspect(context[:name])}: #{path} is not a world description"

      {:error, errors} ->
        raise ArgumentError, ThinkingCap.Config.format_errors(errors)
    end
  end

  def read_wdf(_context), do: nil

  @doc "The robot's description; `needing` says what for, when the ADF gives no RDF."
  @spec describe!(map(), String.t()) :: Description.t()
  def describe!(%{rdf: rdf} = context, _needing) when is_binary(rdf) do
    case Description.load(rdf) do
      {:ok, d} -> d
      {:error, message} -> raise ArgumentError, "#{inspect(context[:name])}: #{message}"
    end
  end

  def describe!(context, needing),
    do: raise(ArgumentError, "#{inspect(context[:name])}: #{needing} needs the ADF's rdf:")
end
